/* Chi-square (normalised innovation squared) gate, 1 degree of freedom, with a lock-out guard. */
#ifndef UWB_GATE_CHI2_H
#define UWB_GATE_CHI2_H

#include <stdint.h>

/* A link with an anchor whose links have been rejected for longer than this [us] skips the gate (as the
 * kinematic gate's window widens): the filter cannot lock an anchor out once the estimate was pulled
 * away from it (docs/bias-network.md "Outlier rejection among obstacles"). Isolated outliers, and the
 * first 200 ms of a run of them, are still rejected. */
#define GATE_CHI2_REOPEN_US 200000

/* 1 if innovation^2 / S <= threshold (S = H P H^T + R > 0). */
int gate_chi2_pass(float innovation, float S, float threshold);

/* 1 if the gate is open for a link whose anchors had been rejected for rejected_us (gate_kinematic_t). */
int gate_chi2_reopened(int64_t rejected_us);

#endif
