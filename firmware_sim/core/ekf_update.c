/* The EKF's scalar measurement update (H = [h, 0...]): P H^T, S and the Mahalanobis distance for the
 * gates, then the gain, the state correction and P in Joseph form (ekf_core.h). */
#include "ekf_core.h"

#include <math.h>

void ekf_scalar_prepare(const ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation,
                        float r_var)
{
    const float h0 = h[0], h1 = h[1], h2 = h[2]; /* in registers: m's stores could alias h */
    int i;
    m->h[0] = h0;
    m->h[1] = h1;
    m->h[2] = h2;
    /* H has only three nonzero entries: P H^T is three columns of P, not a 9x9 product. */
    for (i = 0; i < EKF_N; i++) {
        m->ph[i] = ekf->P[i][0] * h0 + ekf->P[i][1] * h1 + ekf->P[i][2] * h2;
        m->K[i] = 0.0f;
    }
    m->r_var = r_var;
    m->innovation = innovation;
    m->S = h0 * m->ph[0] + h1 * m->ph[1] + h2 * m->ph[2] + r_var;
    m->mahalanobis = fabsf(innovation) / sqrtf(m->S);
}

/* The gain, s = P H^T and u = R K - w (w = P1 H^T) of one update in locals (no aliasing with P: they stay in
 * registers while P is written). */
typedef struct {
    float K[EKF_N], s[EKF_N], u[EKF_N];
} joseph_t;

/* Entry (i, j) of the Joseph form's second step (below): P1_ij + (R K_i - w_i) K_j, P1 = P - K s^T. */
static inline float joseph_entry(const float *P, const joseph_t *t, int i, int j)
{
    const float p1 = P[i * EKF_N + j] - t->K[i] * t->s[j];
    return p1 + t->u[i] * t->K[j];
}

/* The pair average (P2_ij + P2_ji) / 2, i < j. A pair reads P_ij and P_ji only, before writing them. */
static inline float joseph_pair(const float *P, const joseph_t *t, int i, int j)
{
    return 0.5f * (joseph_entry(P, t, i, j) + joseph_entry(P, t, j, i));
}

/* One pair on the clamp's usual path (every variance in range): bounded and mirrored. */
static inline void put_pair(float *P, const joseph_t *t, int i, int j)
{
    const float v = ekf_clamp_cov(joseph_pair(P, t, i, j));
    P[i * EKF_N + j] = v;
    P[j * EKF_N + i] = v;
}

/* P2 written over P when every new variance is in range: the clamp's usual path applied on the way (bounds,
 * mirror, P_MIN floor), what ekf_sym_clamp_upper would do after the pass. Two rows at a time: rows i and i + 1
 * share each column's K_j, s_j, u_j (the same numbers in any order: no pair reads another's entries). */
static void joseph_write_clamped(float *P, const joseph_t *t, const float *diag)
{
    int i, j;
    for (i = 0; i + 1 < EKF_N; i += 2) {
        put_pair(P, t, i, i + 1);
        for (j = i + 2; j < EKF_N; j++) {
            put_pair(P, t, i, j);
            put_pair(P, t, i + 1, j);
        }
    }
    for (i = 0; i < EKF_N; i++) {
        P[i * EKF_N + i] = ekf_var_floor(diag[i]);
    }
}

/* The rare path: P2's upper triangle and diagonal as they are, for ekf_sym_clamp_upper. */
static void joseph_write_upper(float *P, const joseph_t *t, const float *diag)
{
    int i, j;
    for (i = 0; i < EKF_N; i++) {
        for (j = i + 1; j < EKF_N; j++) {
            P[i * EKF_N + j] = joseph_pair(P, t, i, j);
        }
        P[i * EKF_N + i] = diag[i];
    }
}

void ekf_scalar_apply(ekf_t *ekf, ekf_scalar_t *m)
{
    const float inv_s = 1.0f / m->S;
    const float *h = m->h;
    float *P = &ekf->P[0][0];
    float diag[EKF_N];
    joseph_t t;
    int i, in_range = 1;
    for (i = 0; i < EKF_N; i++) {
        t.K[i] = m->ph[i] * inv_s;
        t.s[i] = m->ph[i];
        m->K[i] = t.K[i];
        ekf->x[i] += t.K[i] * m->innovation;
    }
    /* Joseph form P <- (I - K H) P (I - K H)^T + K R K^T as two rank-one corrections (H = [h 0]):
     * P1 = P - K s^T (s = P H^T), then P2 = P1 - w K^T + R K K^T = P1 + (R K - w) K^T with w = P1 H^T
     * measured on the rounded P1: that is what keeps the Joseph form accurate in float32 (P - s s^T / S,
     * equal in exact arithmetic, drifts by millimetres from the float64 twin after a divergence; the factored
     * (R K_i - w_i) K_j is one product less per entry than R K_i K_j - w_i K_j, docs/qemu.md). w needs P1's first
     * three columns only (27 entries). P2 is symmetrised as (P2_ij + P2_ji) / 2 pair by pair, the upper
     * triangle mirrored by the clamp: the same numbers as the full 9x9 passes and ekf_sym_clamp_flat. The
     * new variances come first: when all are in range (always in flight) the clamp is fused into the pass. */
    for (i = 0; i < EKF_N; i++) {
        const float ki = t.K[i];
        const float w = (P[i * EKF_N] - ki * t.s[0]) * h[0] + (P[i * EKF_N + 1] - ki * t.s[1]) * h[1] +
                        (P[i * EKF_N + 2] - ki * t.s[2]) * h[2];
        float d;
        t.u[i] = m->r_var * ki - w;
        d = joseph_entry(P, &t, i, i);
        diag[i] = 0.5f * (d + d);
        in_range &= ekf_var_in_range(diag[i]);
    }
    if (in_range) {
        joseph_write_clamped(P, &t, diag);
    } else {
        joseph_write_upper(P, &t, diag);
        ekf_sym_clamp_upper(P);
    }
}

void ekf_scalar_update(ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation, float r_var)
{
    ekf_scalar_prepare(ekf, m, h, innovation, r_var);
    ekf_scalar_apply(ekf, m);
}
