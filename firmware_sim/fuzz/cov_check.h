/* The positive-definiteness check of a covariance, shared by the EKF tests (tests/ekf_fixture.h) and the
 * long-flight health probe (fuzz/cov_health.c). Header-only (static inline). */
#ifndef UWB_COV_CHECK_H
#define UWB_COV_CHECK_H

#include <math.h>

#include "ekf_core.h"

/* The smallest pivot of P's Cholesky factorisation P = L L^T in double (P row-major, EKF_N x EKF_N): > 0 iff
 * P is positive definite. Stops at the first pivot that is not > 0 (or NaN) and returns it. */
static inline double cov_min_pivot(const float *P)
{
    double L[EKF_N][EKF_N], min_pivot = HUGE_VAL;
    int i, j, k;
    for (j = 0; j < EKF_N; j++) {
        double d = P[j * EKF_N + j];
        for (k = 0; k < j; k++) {
            d -= L[j][k] * L[j][k];
        }
        if (!(d > 0.0)) {
            return d;
        }
        min_pivot = d < min_pivot ? d : min_pivot;
        L[j][j] = sqrt(d);
        for (i = j + 1; i < EKF_N; i++) {
            double s = P[i * EKF_N + j];
            for (k = 0; k < j; k++) {
                s -= L[i][k] * L[j][k];
            }
            L[i][j] = s / L[j][j];
        }
    }
    return min_pivot;
}

#endif
