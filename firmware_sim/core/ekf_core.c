/* Error-state EKF core. Equations: docs/ARCHITECTURE.md and the Crazyflie notes (kalman_core),
 * written here from the equations. Everything is float: the target is a Cortex-M4F.
 *
 * Process noise (documented here, mirrored by harness/twin/ekf.py). Both prediction modes model a
 * continuous white acceleration, so the injected uncertainty does not depend on the prediction rate:
 *   IMU mode, per prediction of length dt, with Sa = diag(acc_xy^2, acc_xy^2, acc_z^2) (body frame):
 *     Q_vv = Sa dt,  Q_pv = R Sa dt^2/2,  Q_pp = R Sa R^T dt^3/3,
 *     Q_dd = diag(g_rp^2, g_rp^2, g_yaw^2) dt  (gyro white noise, constants below).
 *   UWB-only mode, per axis with q = proc_cv_acc:
 *     Q_pp = q^2 dt^3/3,  Q_pv = q^2 dt^2/2,  Q_vv = q^2 dt.
 */
#include "ekf_core.h"

#include <math.h>
#include <string.h>

/* Gyro white-noise density [rad/s/sqrt(Hz)] used as attitude process noise. Small: the attitude is
 * propagated by the gyro, only weakly observed through UWB, and must not random-walk away. */
#define EKF_GYRO_NOISE_RP 0.01f
#define EKF_GYRO_NOISE_YAW 0.01f

/* The finalize step only trusts attitude errors below this magnitude [rad] (as the Crazyflie). */
#define EKF_ATT_ERR_MAX 10.0f

static void quat_to_rot(const float q[4], float R[3][3])
{
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    R[0][0] = w * w + x * x - y * y - z * z;
    R[0][1] = 2.0f * (x * y - w * z);
    R[0][2] = 2.0f * (x * z + w * y);
    R[1][0] = 2.0f * (x * y + w * z);
    R[1][1] = w * w - x * x + y * y - z * z;
    R[1][2] = 2.0f * (y * z - w * x);
    R[2][0] = 2.0f * (x * z - w * y);
    R[2][1] = 2.0f * (y * z + w * x);
    R[2][2] = w * w - x * x - y * y + z * z;
}

/* q <- normalise(q (x) exp(v)), v a body-frame rotation vector [rad]. */
static void quat_rotate_body(float q[4], const float v[3])
{
    const float theta = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    /* sin(theta/2)/theta -> 1/2 as theta -> 0: avoid 0/0 for tiny rotations. */
    const float s = theta > 1e-6f ? sinf(0.5f * theta) / theta : 0.5f;
    const float dw = cosf(0.5f * theta), dx = s * v[0], dy = s * v[1], dz = s * v[2];
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    float n;
    q[0] = w * dw - x * dx - y * dy - z * dz;
    q[1] = w * dx + x * dw + y * dz - z * dy;
    q[2] = w * dy - x * dz + y * dw + z * dx;
    q[3] = w * dz + x * dy - y * dx + z * dw;
    n = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    q[0] /= n;
    q[1] /= n;
    q[2] /= n;
    q[3] /= n;
}

/* Second-order rotation of the attitude-error covariance for a half-angle vector d (reference). */
static void att_block(const float d[3], float G[3][3])
{
    G[0][0] = 1.0f - 0.5f * d[1] * d[1] - 0.5f * d[2] * d[2];
    G[0][1] = d[2] + 0.5f * d[0] * d[1];
    G[0][2] = -d[1] + 0.5f * d[0] * d[2];
    G[1][0] = -d[2] + 0.5f * d[0] * d[1];
    G[1][1] = 1.0f - 0.5f * d[0] * d[0] - 0.5f * d[2] * d[2];
    G[1][2] = d[0] + 0.5f * d[1] * d[2];
    G[2][0] = d[1] + 0.5f * d[0] * d[2];
    G[2][1] = -d[0] + 0.5f * d[1] * d[2];
    G[2][2] = 1.0f - 0.5f * d[0] * d[0] - 0.5f * d[1] * d[1];
}

/* On a flat row-major 9x9 array: GCC 12 misreads the array parameter's bounds at some call sites
 * (a false -Wstringop-overflow). */
static void sym_clamp_flat(float *P)
{
    /* Clamping entries one by one (as the Crazyflie does) can make P indefinite: a variance cut to
     * EKF_P_MAX next to an uncut covariance. Then S = H P H^T + R can go negative and an update throws
     * the state kilometres away (rcv_twr sequence 3). So a variance above EKF_P_MAX scales its whole
     * row and column by s_i = sqrt(EKF_P_MAX / P_ii): P <- D P D is a congruence, it keeps P positive
     * semi-definite and every correlation coefficient. A non-finite variance loses its correlations. */
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
            } else if (bad[i] || bad[j] || isnan(v)) {
                v = 0.0f;
            } else if (v > EKF_P_MAX) {
                v = EKF_P_MAX;
            } else if (v < -EKF_P_MAX) {
                v = -EKF_P_MAX;
            }
            P[i * EKF_N + j] = v;
            P[j * EKF_N + i] = v;
        }
    }
}

void ekf_sym_clamp(float P[EKF_N][EKF_N])
{
    sym_clamp_flat(&P[0][0]);
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

/* First index where row i of the IMU transition matrix can be nonzero: A is block upper
 * triangular (position <- all, velocity <- velocity/attitude, attitude <- attitude). */
static const uint8_t imu_row_start[EKF_N] = {0, 0, 0, 3, 3, 3, 6, 6, 6};

void ekf_predict_imu(ekf_t *ekf, const ekf_noise_t *noise, const float acc[3], const float gyro[3],
                     float dt)
{
    float A[EKF_N][EKF_N];
    float AP[EKF_N][EKF_N];
    float (*R)[3] = ekf->R;
    float *x = ekf->x;
    const float px = x[EKF_PX], py = x[EKF_PY], pz = x[EKF_PZ];
    const float wx = gyro[0], wy = gyro[1], wz = gyro[2];
    const float gdt = EKF_GRAVITY * dt, dt2 = dt * dt;
    float d[3], G[3][3], Sa[3], dpos[3], rot[3];
    int i, j, k;

    /* --- linearised transition A (9x9) ------------------------------------------------------ */
    memset(A, 0, sizeof A);
    for (i = 0; i < EKF_N; i++) {
        A[i][i] = 1.0f;
    }
    for (i = 0; i < 3; i++) {
        /* position <- body velocity */
        A[i][EKF_PX] = R[i][0] * dt;
        A[i][EKF_PY] = R[i][1] * dt;
        A[i][EKF_PZ] = R[i][2] * dt;
        /* position <- attitude error: -R [p]x dt */
        A[i][EKF_D0] = (py * R[i][2] - pz * R[i][1]) * dt;
        A[i][EKF_D1] = (-px * R[i][2] + pz * R[i][0]) * dt;
        A[i][EKF_D2] = (px * R[i][1] - py * R[i][0]) * dt;
    }
    /* velocity <- velocity: I - [w]x dt */
    A[EKF_PX][EKF_PY] = wz * dt;
    A[EKF_PX][EKF_PZ] = -wy * dt;
    A[EKF_PY][EKF_PX] = -wz * dt;
    A[EKF_PY][EKF_PZ] = wx * dt;
    A[EKF_PZ][EKF_PX] = wy * dt;
    A[EKF_PZ][EKF_PY] = -wx * dt;
    /* velocity <- attitude error: -g [R^T e3]x dt */
    A[EKF_PX][EKF_D1] = gdt * R[2][2];
    A[EKF_PX][EKF_D2] = -gdt * R[2][1];
    A[EKF_PY][EKF_D0] = -gdt * R[2][2];
    A[EKF_PY][EKF_D2] = gdt * R[2][0];
    A[EKF_PZ][EKF_D0] = gdt * R[2][1];
    A[EKF_PZ][EKF_D1] = -gdt * R[2][0];
    /* attitude error <- attitude error */
    d[0] = 0.5f * wx * dt;
    d[1] = 0.5f * wy * dt;
    d[2] = 0.5f * wz * dt;
    att_block(d, G);
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++) {
            A[EKF_D0 + i][EKF_D0 + j] = G[i][j];
        }
    }

    /* --- P = A P A^T, skipping the structural zeros of A ------------------------------------ */
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            float s = 0.0f;
            for (k = imu_row_start[i]; k < EKF_N; k++) {
                s += A[i][k] * ekf->P[k][j];
            }
            AP[i][j] = s;
        }
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            float s = 0.0f;
            for (k = imu_row_start[j]; k < EKF_N; k++) {
                s += AP[i][k] * A[j][k];
            }
            ekf->P[i][j] = s;
        }
    }

    /* --- process noise (see the file comment), with the R of the start of the step ---------- */
    Sa[0] = noise->acc_xy * noise->acc_xy;
    Sa[1] = Sa[0];
    Sa[2] = noise->acc_z * noise->acc_z;
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++) {
            /* (R Sa R^T)_ij and (R Sa)_ij */
            float rsr = R[i][0] * Sa[0] * R[j][0] + R[i][1] * Sa[1] * R[j][1] + R[i][2] * Sa[2] * R[j][2];
            float pv = R[i][j] * Sa[j] * dt2 * 0.5f;
            ekf->P[i][j] += rsr * dt2 * dt * (1.0f / 3.0f);
            ekf->P[i][EKF_PX + j] += pv;
            ekf->P[EKF_PX + j][i] += pv;
        }
        ekf->P[EKF_PX + i][EKF_PX + i] += Sa[i] * dt;
    }
    ekf->P[EKF_D0][EKF_D0] += EKF_GYRO_NOISE_RP * EKF_GYRO_NOISE_RP * dt;
    ekf->P[EKF_D1][EKF_D1] += EKF_GYRO_NOISE_RP * EKF_GYRO_NOISE_RP * dt;
    ekf->P[EKF_D2][EKF_D2] += EKF_GYRO_NOISE_YAW * EKF_GYRO_NOISE_YAW * dt;

    /* --- nominal state: full accelerometer (specific force), body-frame velocity ------------ */
    dpos[0] = px * dt + acc[0] * dt2 * 0.5f;
    dpos[1] = py * dt + acc[1] * dt2 * 0.5f;
    dpos[2] = pz * dt + acc[2] * dt2 * 0.5f;
    for (i = 0; i < 3; i++) {
        x[EKF_X + i] += R[i][0] * dpos[0] + R[i][1] * dpos[1] + R[i][2] * dpos[2];
    }
    x[EKF_Z] -= EKF_GRAVITY * dt2 * 0.5f;
    x[EKF_PX] = px + dt * (acc[0] + wz * py - wy * pz - EKF_GRAVITY * R[2][0]);
    x[EKF_PY] = py + dt * (acc[1] - wz * px + wx * pz - EKF_GRAVITY * R[2][1]);
    x[EKF_PZ] = pz + dt * (acc[2] + wy * px - wx * py - EKF_GRAVITY * R[2][2]);
    rot[0] = wx * dt;
    rot[1] = wy * dt;
    rot[2] = wz * dt;
    quat_rotate_body(ekf->q, rot);
    quat_to_rot(ekf->q, ekf->R);

    sym_clamp_flat(&ekf->P[0][0]);
}

int ekf_imu_sample(ekf_t *ekf, const ekf_noise_t *noise, uint64_t t_us, const float acc[3],
                   const float gyro[3])
{
    int i;
    if (!ekf->has_time) {
        ekf->t_us = t_us;
        ekf->has_time = 1;
        return 0;
    }
    for (i = 0; i < 3; i++) {
        ekf->acc_sum[i] += acc[i];
        ekf->gyro_sum[i] += gyro[i];
    }
    ekf->imu_count++;
    if (t_us >= ekf->t_us && t_us - ekf->t_us >= EKF_PREDICT_INTERVAL_US) {
        const float inv = 1.0f / (float)ekf->imu_count;
        const float dt = (float)(t_us - ekf->t_us) * 1e-6f;
        float a[3], g[3];
        for (i = 0; i < 3; i++) {
            a[i] = ekf->acc_sum[i] * inv;
            g[i] = ekf->gyro_sum[i] * inv;
            ekf->acc_sum[i] = 0.0f;
            ekf->gyro_sum[i] = 0.0f;
        }
        ekf->imu_count = 0;
        ekf_predict_imu(ekf, noise, a, g, dt);
        ekf->t_us = t_us;
        return 1;
    }
    return 0;
}

void ekf_predict_cv(ekf_t *ekf, float q_acc, float dt)
{
    const float q2 = q_acc * q_acc;
    int i, j;
    /* A = I + dt E, E mapping velocity into position. In place: row i (< 3) only reads row i+3,
     * column j (< 3) only reads column j+3, neither of which is written in its pass. */
    for (i = 0; i < 3; i++) {
        ekf->x[EKF_X + i] += ekf->x[EKF_PX + i] * dt;
        for (j = 0; j < EKF_N; j++) {
            ekf->P[i][j] += dt * ekf->P[EKF_PX + i][j];
        }
    }
    for (j = 0; j < 3; j++) {
        for (i = 0; i < EKF_N; i++) {
            ekf->P[i][j] += dt * ekf->P[i][EKF_PX + j];
        }
    }
    for (i = 0; i < 3; i++) {
        const float qpv = q2 * dt * dt * 0.5f;
        ekf->P[i][i] += q2 * dt * dt * dt * (1.0f / 3.0f);
        ekf->P[i][EKF_PX + i] += qpv;
        ekf->P[EKF_PX + i][i] += qpv;
        ekf->P[EKF_PX + i][EKF_PX + i] += q2 * dt;
    }
    sym_clamp_flat(&ekf->P[0][0]);
}

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
    sym_clamp_flat(&ekf->P[0][0]);
}

void ekf_scalar_update(ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation, float r_var)
{
    ekf_scalar_prepare(ekf, m, h, innovation, r_var);
    ekf_scalar_apply(ekf, m);
}

void ekf_finalize(ekf_t *ekf)
{
    const float v[3] = {ekf->x[EKF_D0], ekf->x[EKF_D1], ekf->x[EKF_D2]};
    const int small = fabsf(v[0]) < EKF_ATT_ERR_MAX && fabsf(v[1]) < EKF_ATT_ERR_MAX &&
                      fabsf(v[2]) < EKF_ATT_ERR_MAX;
    if (small && (v[0] != 0.0f || v[1] != 0.0f || v[2] != 0.0f)) {
        float d[3], G[3][3], T[3][3];
        int i, a, b;
        quat_rotate_body(ekf->q, v);
        quat_to_rot(ekf->q, ekf->R);
        /* P = A P A^T with A = blockdiag(I6, G): only the attitude rows/columns change. */
        d[0] = 0.5f * v[0];
        d[1] = 0.5f * v[1];
        d[2] = 0.5f * v[2];
        att_block(d, G);
        for (i = 0; i < EKF_D0; i++) {
            float t[3];
            for (a = 0; a < 3; a++) {
                t[a] = G[a][0] * ekf->P[i][EKF_D0] + G[a][1] * ekf->P[i][EKF_D1] +
                       G[a][2] * ekf->P[i][EKF_D2];
            }
            for (a = 0; a < 3; a++) {
                ekf->P[i][EKF_D0 + a] = t[a];
                ekf->P[EKF_D0 + a][i] = t[a];
            }
        }
        for (a = 0; a < 3; a++) {
            for (b = 0; b < 3; b++) {
                T[a][b] = G[a][0] * ekf->P[EKF_D0][EKF_D0 + b] + G[a][1] * ekf->P[EKF_D1][EKF_D0 + b] +
                          G[a][2] * ekf->P[EKF_D2][EKF_D0 + b];
            }
        }
        for (a = 0; a < 3; a++) {
            for (b = 0; b < 3; b++) {
                ekf->P[EKF_D0 + a][EKF_D0 + b] = T[a][0] * G[b][0] + T[a][1] * G[b][1] + T[a][2] * G[b][2];
            }
        }
        sym_clamp_flat(&ekf->P[0][0]);
    }
    ekf->x[EKF_D0] = 0.0f;
    ekf->x[EKF_D1] = 0.0f;
    ekf->x[EKF_D2] = 0.0f;
}

int ekf_is_finite(const ekf_t *ekf)
{
    int i;
    for (i = 0; i < EKF_N; i++) {
        if (!isfinite(ekf->x[i]) || !isfinite(ekf->P[i][i])) {
            return 0;
        }
    }
    for (i = 0; i < 4; i++) {
        if (!isfinite(ekf->q[i])) {
            return 0;
        }
    }
    return 1;
}

void ekf_quat_to_rpy(const float q[4], float rpy[3])
{
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    float sp = 2.0f * (w * y - z * x);
    sp = sp > 1.0f ? 1.0f : (sp < -1.0f ? -1.0f : sp);
    rpy[0] = atan2f(2.0f * (w * x + y * z), 1.0f - 2.0f * (x * x + y * y));
    rpy[1] = asinf(sp);
    rpy[2] = atan2f(2.0f * (w * z + x * y), 1.0f - 2.0f * (y * y + z * z));
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
