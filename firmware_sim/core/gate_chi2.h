/* Chi-square (normalised innovation squared) gate, 1 degree of freedom. */
#ifndef UWB_GATE_CHI2_H
#define UWB_GATE_CHI2_H

/* 1 if innovation^2 / S <= threshold (S = H P H^T + R > 0). */
int gate_chi2_pass(float innovation, float S, float threshold);

#endif
