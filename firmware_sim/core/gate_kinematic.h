/* Kinematic ("model-based") outlier gate of the paper: the innovation cannot exceed how far the
 * tag can have moved since the state time, d_max = |v| dt + a_max dt^2 / 2. */
#ifndef UWB_GATE_KINEMATIC_H
#define UWB_GATE_KINEMATIC_H

#include <stdint.h>

/* dt [s] = max(t_meas - t_ref, dt_min); have_ref = 0 (no reference time yet) gives dt_min. */
float gate_kinematic_dt(int64_t dt_us, int have_ref, float dt_min);

/* d_max [m] for velocity v (any frame: only its norm is used), dt [s] and a_max [m/s^2]. */
float gate_kinematic_dmax(const float v[3], float dt, float a_max);

/* 1 if |innovation| <= factor * d_max (factor 1 for TWR, 2 for TDoA: two ranges differ). */
int gate_kinematic_pass(float innovation, float d_max, float factor);

#endif
