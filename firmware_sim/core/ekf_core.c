/* Error-state EKF core. Equations: docs/ARCHITECTURE.md and the Crazyflie notes (kalman_core),
 * written here from the equations. Everything is float: the target is a Cortex-M4F.
 * Here: the covariance clamp, initialisation, the finalize step (attitude error into q), checks and the
 * externalised state. Prediction: ekf_predict.c; measurement update: ekf_update.c; quaternion
 * helpers: ekf_quat.h.
 */
#include "ekf_core.h"

#include <math.h>
#include <string.h>

#include "ekf_quat.h"

/* The finalize step only trusts attitude errors below this magnitude [rad] (as the Crazyflie). */
#define EKF_ATT_ERR_MAX 10.0f

float ekf_clamp_cov_out(float v)
{
    if (v != v) {
        return 0.0f;
    }
    return v > 0.0f ? EKF_P_MAX : -EKF_P_MAX;
}

/* 1 if every variance is finite and <= EKF_P_MAX: then no row needs scaling and the clamp is entry-wise. */
static int variances_in_range(const float *P)
{
    int i;
    for (i = 0; i < EKF_N; i++) {
        if (!ekf_var_in_range(P[i * EKF_N + i])) {
            return 0;
        }
    }
    return 1;
}

/* The general clamp: a variance above EKF_P_MAX or a non-finite one (see ekf_sym_clamp_flat). */
static void sym_clamp_scaled(float *P)
{
    float s[EKF_N];
    uint8_t bad[EKF_N];
    int i, j;
    for (i = 0; i < EKF_N; i++) {
        const float d = P[i * EKF_N + i];
        bad[i] = (uint8_t)(isfinite(d) ? 0 : 1);
        s[i] = (!bad[i] && d > EKF_P_MAX) ? sqrtf(EKF_P_MAX / d) : 1.0f;
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = i; j < EKF_N; j++) {
            float v = 0.5f * (P[i * EKF_N + j] + P[j * EKF_N + i]) * s[i] * s[j];
            if (i == j) {
                v = (bad[i] || isnan(v) || v > EKF_P_MAX) ? EKF_P_MAX : (v < EKF_P_MIN ? EKF_P_MIN : v);
            } else if (bad[i] || bad[j]) {
                v = 0.0f;
            } else {
                v = ekf_clamp_cov(v);
            }
            P[i * EKF_N + j] = v;
            P[j * EKF_N + i] = v;
        }
    }
}

/* The entry-wise bounds of a symmetric P whose variances are all in range, upper triangle mirrored; with
 * `average` the upper entry is first (P_ij + P_ji) / 2 (constant at each call: two specialised copies). */
static inline void clamp_in_range(float *P, int average)
{
    int i, j;
    for (i = 0; i < EKF_N; i++) {
        float *row = P + i * EKF_N;
        const float d = row[i];
        row[i] = ekf_var_floor(d);
        for (j = i + 1; j < EKF_N; j++) {
            const float v = ekf_clamp_cov(average ? 0.5f * (row[j] + P[j * EKF_N + i]) : row[j]);
            row[j] = v;
            P[j * EKF_N + i] = v;
        }
    }
}

void ekf_sym_clamp_flat(float *P)
{
    /* Clamping entries one by one (as the Crazyflie does) can make P indefinite: a variance cut to
     * EKF_P_MAX next to an uncut covariance. Then S = H P H^T + R can go negative and an update throws
     * the state kilometres away (rcv_twr sequence 3). So a variance above EKF_P_MAX scales its whole
     * row and column by s_i = sqrt(EKF_P_MAX / P_ii): P <- D P D is a congruence, it keeps P positive
     * semi-definite and every correlation coefficient. A non-finite variance loses its correlations.
     * When no variance needs it (the usual case) every s_i is 1 and the bounds are entry-wise on
     * (P + P^T) / 2: the same result without the products. */
    if (variances_in_range(P)) {
        clamp_in_range(P, 1);
    } else {
        sym_clamp_scaled(P);
    }
}

void ekf_sym_clamp_upper(float *P)
{
    int i, j;
    if (variances_in_range(P)) {
        clamp_in_range(P, 0);
        return;
    }
    for (i = 1; i < EKF_N; i++) {
        for (j = 0; j < i; j++) {
            P[i * EKF_N + j] = P[j * EKF_N + i];
        }
    }
    sym_clamp_scaled(P);
}

void ekf_sym_clamp(float P[EKF_N][EKF_N])
{
    ekf_sym_clamp_flat(&P[0][0]);
}

static float clamp_var(float v)
{
    return v > EKF_P_MAX ? EKF_P_MAX : (v < EKF_P_MIN ? EKF_P_MIN : v);
}

void ekf_init(ekf_t *ekf, const float pos[3], float std_xy, float std_z)
{
    int i;
    memset(ekf, 0, sizeof *ekf);
    ekf->x[EKF_X] = pos[0];
    ekf->x[EKF_Y] = pos[1];
    ekf->x[EKF_Z] = pos[2];
    ekf->q[0] = 1.0f;
    quat_to_rot(ekf->q, ekf->R);
    /* Within the covariance bounds from the start: a huge (valid) init std would otherwise square
     * to inf, and the divergence guard would re-initialise into the same inf forever. */
    ekf->P[EKF_X][EKF_X] = clamp_var(std_xy * std_xy);
    ekf->P[EKF_Y][EKF_Y] = clamp_var(std_xy * std_xy);
    ekf->P[EKF_Z][EKF_Z] = clamp_var(std_z * std_z);
    for (i = EKF_PX; i <= EKF_PZ; i++) {
        ekf->P[i][i] = EKF_INIT_STD_VEL * EKF_INIT_STD_VEL;
    }
    for (i = EKF_D0; i <= EKF_D2; i++) {
        ekf->P[i][i] = EKF_INIT_STD_ATT * EKF_INIT_STD_ATT;
    }
}

/* out = G (x, y, z)^T, each sum in the dense product's order (written out: straight-line code). */
static inline void g_times(const float G[3][3], float x, float y, float z, float out[3])
{
    out[0] = G[0][0] * x + G[0][1] * y + G[0][2] * z;
    out[1] = G[1][0] * x + G[1][1] * y + G[1][2] * z;
    out[2] = G[2][0] * x + G[2][1] * y + G[2][2] * z;
}

/* The attitude block's new value M = G P_att G^T (T = G P_att column by column, then M's rows T_a G^T; not
 * symmetric in float); returns 1 if its variances are in range. */
static int rotated_attitude_block(const float *P, const float G[3][3], float M[3][3])
{
    const float *pa = P + EKF_D0 * EKF_N + EKF_D0;
    float T[3][3];
    int a;
    for (a = 0; a < 3; a++) {
        float col[3];
        g_times(G, pa[a], pa[EKF_N + a], pa[2 * EKF_N + a], col);
        T[0][a] = col[0];
        T[1][a] = col[1];
        T[2][a] = col[2];
    }
    for (a = 0; a < 3; a++) {
        g_times(G, T[a][0], T[a][1], T[a][2], M[a]);
    }
    return ekf_var_in_range(M[0][0]) & ekf_var_in_range(M[1][1]) & ekf_var_in_range(M[2][2]);
}

/* P_ij = P_ji = v. */
static inline void put_sym(float *P, int i, int j, float v)
{
    P[i * EKF_N + j] = v;
    P[j * EKF_N + i] = v;
}

/* P = A P A^T with A = blockdiag(I6, G): only the attitude rows and columns change; then ekf_sym_clamp_flat.
 * P entered as the clamp leaves it (every caller finalizes right after an update: its variances are in
 * [EKF_P_MIN, EKF_P_MAX], and the six position and velocity ones do not change here), so when the new attitude
 * variances are in range too (the usual path) every other entry is a fixed point of the clamp, and the clamp
 * is applied to the 27 new entries as they are written (G P[i][D0..D2] mirrored as it is: (v + v) / 2 = v; the
 * attitude block's pairs averaged): the same numbers as the full pass. */
static void rotate_covariance(float *P, const float G[3][3])
{
    float M[3][3];
    const int fast = rotated_attitude_block(P, G, M);
    int i;
    for (i = 0; i < EKF_D0; i++) {
        float c[3];
        g_times(G, P[i * EKF_N + EKF_D0], P[i * EKF_N + EKF_D1], P[i * EKF_N + EKF_D2], c);
        if (fast) {
            c[0] = ekf_clamp_cov(c[0]);
            c[1] = ekf_clamp_cov(c[1]);
            c[2] = ekf_clamp_cov(c[2]);
        }
        put_sym(P, i, EKF_D0, c[0]);
        put_sym(P, i, EKF_D1, c[1]);
        put_sym(P, i, EKF_D2, c[2]);
    }
    if (!fast) {
        for (i = 0; i < 9; i++) {
            P[(EKF_D0 + i / 3) * EKF_N + EKF_D0 + i % 3] = M[i / 3][i % 3];
        }
        ekf_sym_clamp_flat(P);
        return;
    }
    for (i = 0; i < 3; i++) {
        P[(EKF_D0 + i) * (EKF_N + 1)] = ekf_var_floor(M[i][i]);
    }
    put_sym(P, EKF_D0, EKF_D1, ekf_clamp_cov(0.5f * (M[0][1] + M[1][0])));
    put_sym(P, EKF_D0, EKF_D2, ekf_clamp_cov(0.5f * (M[0][2] + M[2][0])));
    put_sym(P, EKF_D1, EKF_D2, ekf_clamp_cov(0.5f * (M[1][2] + M[2][1])));
}

/* Velocity zero and known (the position's covariance kept): ekf_core.h. */
void ekf_hold_at_rest(ekf_t *ekf)
{
    int i, j;
    for (i = EKF_PX; i <= EKF_PZ; i++) {
        ekf->x[i] = 0.0f;
        for (j = 0; j < EKF_N; j++) {
            ekf->P[i][j] = 0.0f;
            ekf->P[j][i] = 0.0f;
        }
        ekf->P[i][i] = EKF_P_MIN;
    }
}

void ekf_finalize(ekf_t *ekf)
{
    const float v[3] = {ekf->x[EKF_D0], ekf->x[EKF_D1], ekf->x[EKF_D2]};
    const int small = fabsf(v[0]) < EKF_ATT_ERR_MAX && fabsf(v[1]) < EKF_ATT_ERR_MAX &&
                      fabsf(v[2]) < EKF_ATT_ERR_MAX;
    if (small && (v[0] != 0.0f || v[1] != 0.0f || v[2] != 0.0f)) {
        const float d[3] = {0.5f * v[0], 0.5f * v[1], 0.5f * v[2]};
        float G[3][3];
        quat_rotate_body(ekf->q, v);
        quat_to_rot(ekf->q, ekf->R);
        att_block(d, G);
        rotate_covariance(&ekf->P[0][0], (const float (*)[3])G);
    }
    ekf->x[EKF_D0] = 0.0f;
    ekf->x[EKF_D1] = 0.0f;
    ekf->x[EKF_D2] = 0.0f;
}

int ekf_is_finite(const ekf_t *ekf)
{
    /* v - v is 0 for a finite v and NaN for an infinite or NaN one: one test for the 22 values (the
     * supervisor runs this after every prediction and update; 22 isfinite tests took ~150 instructions). */
    float z = 0.0f;
    int i;
    for (i = 0; i < EKF_N; i++) {
        z += (ekf->x[i] - ekf->x[i]) + (ekf->P[i][i] - ekf->P[i][i]);
    }
    for (i = 0; i < 4; i++) {
        z += ekf->q[i] - ekf->q[i];
    }
    return z == 0.0f;
}

int ekf_state_finite(const ekf_t *ekf)
{
    const float *x = ekf->x, *q = ekf->q;
    /* as ekf_is_finite, written out (no loop counter) */
    const float z = (x[0] - x[0]) + (x[1] - x[1]) + (x[2] - x[2]) + (x[3] - x[3]) + (x[4] - x[4]) + (x[5] - x[5]) +
                    (x[6] - x[6]) + (x[7] - x[7]) + (x[8] - x[8]) + (q[0] - q[0]) + (q[1] - q[1]) + (q[2] - q[2]) +
                    (q[3] - q[3]);
    return z == 0.0f;
}

/* atan(t) for t in [0, 1]: t > tan(pi/12) is reduced by atan(t) = pi/6 + atan((t sqrt3 - 1) / (t + sqrt3)) to
 * |u| <= tan(pi/12), where the odd series to u^11 is within 1e-8 relative of atan (the next term). */
static float atan_unit(float t)
{
    float u = t, base = 0.0f, rest = 0.0f, u2;
    if (t > 0.267949194f) {
        u = (t * 1.73205081f - 1.0f) / (t + 1.73205081f);
        base = 0.523598790f;    /* pi/6 as float */
        rest = -1.45704637e-08f; /* pi/6 - base */
    }
    u2 = u * u;
    return base + (rest + (u + u * u2 * (-0.333333333f +
                                         u2 * (0.2f + u2 * (-0.142857143f + u2 * (0.111111111f + u2 * -0.0909090909f))))));
}

/* atan2 within 3 ulp (tests/test_ekf.c; libm: 1-2): the angles of ekf_quat_to_rpy in ~40 instructions each instead of
 * libm's ~110 (they are the network's attitude inputs, computed for every measurement). Signed zeros and
 * NaN as C99's atan2f. */
static float atan2_fast(float y, float x)
{
    const float ax = fabsf(x), ay = fabsf(y);
    float r;
    if (ax != ax || ay != ay) {
        return x + y;
    }
    if (ay <= ax) {
        r = ax > 0.0f ? atan_unit(ay / ax) : 0.0f;
    } else {
        r = 1.57079637f - (atan_unit(ax / ay) + 4.37113883e-08f); /* pi/2 as float + its rest */
    }
    if (signbit(x)) {
        r = 3.14159274f - (r + 8.74227766e-08f); /* pi likewise */
    }
    return signbit(y) ? -r : r;
}

void ekf_quat_to_rpy(const float q[4], float rpy[3])
{
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    float sp = 2.0f * (w * y - z * x);
    sp = sp > 1.0f ? 1.0f : (sp < -1.0f ? -1.0f : sp);
    rpy[0] = atan2_fast(2.0f * (w * x + y * z), 1.0f - 2.0f * (x * x + y * y));
    rpy[1] = atan2_fast(sp, sqrtf((1.0f - sp) * (1.0f + sp))); /* asin(sp) */
    rpy[2] = atan2_fast(2.0f * (w * z + x * y), 1.0f - 2.0f * (y * y + z * z));
}

void ekf_externalize(const ekf_t *ekf, ekf_state_t *out)
{
    int i;
    for (i = 0; i < 3; i++) {
        out->pos[i] = ekf->x[EKF_X + i];
        out->vel_world[i] = ekf->R[i][0] * ekf->x[EKF_PX] + ekf->R[i][1] * ekf->x[EKF_PY] +
                            ekf->R[i][2] * ekf->x[EKF_PZ];
    }
    for (i = 0; i < 4; i++) {
        out->quat[i] = ekf->q[i];
    }
    for (i = 0; i < EKF_N; i++) {
        out->var[i] = ekf->P[i][i];
    }
    ekf_quat_to_rpy(ekf->q, out->rpy);
}
