/* The EKF's scalar measurement update (H = [h, 0...]): P H^T, S and the Mahalanobis distance for the
 * gates, then the gain, the state correction and P in Joseph form (ekf_core.h). */
#include "ekf_core.h"

#include <math.h>

void ekf_scalar_prepare(const ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation,
                        float r_var)
{
    int i;
    m->h[0] = h[0];
    m->h[1] = h[1];
    m->h[2] = h[2];
    /* H has only three nonzero entries: P H^T is three columns of P, not a 9x9 product. */
    for (i = 0; i < EKF_N; i++) {
        m->ph[i] = ekf->P[i][0] * h[0] + ekf->P[i][1] * h[1] + ekf->P[i][2] * h[2];
        m->K[i] = 0.0f;
    }
    m->r_var = r_var;
    m->innovation = innovation;
    m->S = h[0] * m->ph[0] + h[1] * m->ph[1] + h[2] * m->ph[2] + r_var;
    m->mahalanobis = fabsf(innovation) / sqrtf(m->S);
}

void ekf_scalar_apply(ekf_t *ekf, ekf_scalar_t *m)
{
    const float inv_s = 1.0f / m->S;
    const float *h = m->h;
    float w[EKF_N];
    int i, j;
    for (i = 0; i < EKF_N; i++) {
        m->K[i] = m->ph[i] * inv_s;
        ekf->x[i] += m->K[i] * m->innovation;
    }
    /* Joseph form P = (I - K H) P (I - K H)^T + K R K^T, evaluated as two rank-one corrections
     * because H = [h 0]: first P <- (I - K H) P = P - K (H P) (H P = (P H^T)^T, P symmetric),
     * then P <- P (I - K H)^T + K R K^T = P - w K^T + R K K^T with w = P H^T of the new P.
     * Same result as the matrix products, O(n^2) instead of O(n^3), stays symmetric PSD. */
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            ekf->P[i][j] -= m->K[i] * m->ph[j];
        }
    }
    for (i = 0; i < EKF_N; i++) {
        w[i] = ekf->P[i][0] * h[0] + ekf->P[i][1] * h[1] + ekf->P[i][2] * h[2];
    }
    for (i = 0; i < EKF_N; i++) {
        const float rki = m->r_var * m->K[i];
        for (j = 0; j < EKF_N; j++) {
            ekf->P[i][j] += rki * m->K[j] - w[i] * m->K[j];
        }
    }
    ekf_sym_clamp_flat(&ekf->P[0][0]);
}

void ekf_scalar_update(ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation, float r_var)
{
    ekf_scalar_prepare(ekf, m, h, innovation, r_var);
    ekf_scalar_apply(ekf, m);
}
