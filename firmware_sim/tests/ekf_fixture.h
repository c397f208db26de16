/* Shared by the EKF tests (test_ekf*.c): deterministic random covariances and the symmetry and positive
 * definiteness checks. Header-only (static inline): each test program is one translation unit. */
#ifndef UWB_EKF_FIXTURE_H
#define UWB_EKF_FIXTURE_H

#include <math.h>
#include <string.h>

#include "../fuzz/cov_check.h"
#include "ekf_core.h"

/* Deterministic pseudo-random numbers in [-1, 1). */
static unsigned rng_state = 12345u;
static inline double rnd(void)
{
    rng_state = rng_state * 1664525u + 1013904223u;
    return (double)(rng_state >> 8) / (double)(1u << 23) - 1.0;
}

/* A random SPD covariance P = L L^T + 0.01 I. */
static inline void random_spd(float P[EKF_N][EKF_N])
{
    double L[EKF_N][EKF_N];
    int i, j, k;
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            L[i][j] = j <= i ? 0.5 * rnd() : 0.0;
        }
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            double s = i == j ? 0.01 : 0.0;
            for (k = 0; k < EKF_N; k++) {
                s += L[i][k] * L[j][k];
            }
            P[i][j] = (float)s;
        }
    }
    ekf_sym_clamp(P);
}

/* 1 if P is positive definite (Cholesky in double succeeds). */
static inline int is_pd(float P[EKF_N][EKF_N])
{
    return cov_min_pivot(&P[0][0]) > 0.0;
}

static inline int is_symmetric(float P[EKF_N][EKF_N])
{
    int i, j;
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            if (P[i][j] != P[j][i]) {
                return 0;
            }
        }
    }
    return 1;
}

#endif
