/* Per-anchor bias states: the time-correlated part of the UWB error that the network leaves.
 *
 * Each anchor's link to the tag carries a range bias beta (first-order Gauss-Markov: correlation time
 * BIAS_ST_TAU_S, stationary std BIAS_ST_STD), on top of the network's correction. A TWR range sees
 * beta_A, a TDoA d(B) - d(A) sees beta_B - beta_A. Before a measurement the link's states are propagated
 * to its time and subtracted, and their variance is added to R; after an accepted update they take
 * their share of the innovation (joint update of position and states, taken as uncorrelated before it;
 * the cross-covariance the update creates is dropped, so the EKF keeps its 9 states: Schmidt-style,
 * a scalar filter per anchor). Scalars only, no allocation. harness/twin/bias_states.py is the twin. */
#ifndef UWB_BIAS_STATES_H
#define UWB_BIAS_STATES_H

#include <stdint.h>

#define BIAS_ST_ANCHORS 16   /* = ESTIMATOR_MAX_ANCHORS */
/* Both chosen on UTIL training flights (docs/decisions/2026-11-24-bias-states-design.md); the twin
 * (harness/twin/bias_states.py) keeps the same values (tests/unit/test_twin_constants.py). */
#define BIAS_ST_TAU_S 0.3f   /* correlation time [s] */
#define BIAS_ST_STD 0.12f    /* stationary std [m] of what the network leaves slowly varying */

typedef struct {
    float b[BIAS_ST_ANCHORS];        /* estimated bias of each anchor's range [m] */
    float var[BIAS_ST_ANCHORS];      /* its variance [m^2] */
    uint64_t t_us[BIAS_ST_ANCHORS];  /* time the state refers to */
    uint16_t known;                  /* bit i: anchor i's state started */
} bias_states_t;

/* Forget every state (a new flight). */
void bias_states_reset(bias_states_t *s);

/* Propagate the link's states to t_us (a state not yet started: 0 with the stationary variance) and
 * give the link's bias (TWR: a == b) and its variance. Ids must be < BIAS_ST_ANCHORS. */
void bias_states_predict(bias_states_t *s, uint64_t t_us, uint8_t a, uint8_t b, float *bias, float *var);

/* After an accepted update with innovation y (the link's bias already subtracted) and innovation
 * variance S (including the states' variance): the states' share of y. */
void bias_states_update(bias_states_t *s, uint8_t a, uint8_t b, float y, float S);

#endif
