/* The EKF's time update: IMU mode (linearised error-state transition, body-frame velocity) and UWB-only
 * mode (constant velocity).
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

#include <string.h>


#include "ekf_quat.h"
#include "time_ms.h"

/* Gyro white-noise density [rad/s/sqrt(Hz)] used as attitude process noise. Small: the attitude is
 * propagated by the gyro, only weakly observed through UWB, and must not random-walk away. */
#define EKF_GYRO_NOISE_RP 0.01f
#define EKF_GYRO_NOISE_YAW 0.01f

/* The IMU transition matrix A is block upper triangular: position <- position (I), velocity, attitude;
 * velocity <- velocity, attitude; attitude <- attitude. The covariance products below skip its zeros. */

/* The linearised IMU transition A (9x9) over dt with the averaged gyro w, at the state of the step's start:
 * its non-zero blocks (the zero ones are never read). */
static void imu_transition(const ekf_t *ekf, const float gyro[3], float dt, float A[EKF_N][EKF_N])
{
    const float (*R)[3] = (const float (*)[3])ekf->R;
    const float *x = ekf->x;
    const float px = x[EKF_PX], py = x[EKF_PY], pz = x[EKF_PZ];
    const float wx = gyro[0], wy = gyro[1], wz = gyro[2];
    const float gdt = EKF_GRAVITY * dt;
    float d[3], G[3][3];
    int i, j;

    /* Only the blocks imu_ap and imu_propagate_cov read are written (columns 3..8 of the position and
     * velocity rows, columns 6..8 of the attitude rows): the position rows' identity block is P's row
     * itself there, and clearing all 81 entries cost more than the products skip. */
    for (i = EKF_PX; i <= EKF_PZ; i++) {
        A[i][i] = 1.0f;          /* velocity <- velocity: I - [w]x dt, diagonal */
        A[i][EKF_D0 + i - EKF_PX] = 0.0f; /* velocity <- attitude: -g [R^T e3]x dt, zero diagonal */
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
}

/* s + a[0] v[0] + a[1] v[1] + a[2] v[2] (+ the next three), added in this order: the dense product's order (its
 * skipped terms are exact zeros), written out as straight-line code. The z forms start from the first product
 * instead of 0 + (the same number, up to the sign of an all-zero sum). */
static inline float row3(float s, const float *a, const float *v)
{
    s += a[0] * v[0];
    s += a[1] * v[1];
    s += a[2] * v[2];
    return s;
}

static inline float row3z(const float *a, const float *v)
{
    return a[0] * v[0] + a[1] * v[1] + a[2] * v[2];
}

static inline float row6(float s, const float *a, const float *v)
{
    return row3(row3(s, a, v), a + 3, v + 3);
}

static inline float row6z(const float *a, const float *v)
{
    return row3(row3z(a, v), a + 3, v + 3);
}

/* A column j of P's rows 3..8 (stride EKF_N), or a row of A P's columns 3..8. */
#define COL6(M, j) {(M)[3 * EKF_N + (j)], (M)[4 * EKF_N + (j)], (M)[5 * EKF_N + (j)], (M)[6 * EKF_N + (j)], \
                    (M)[7 * EKF_N + (j)], (M)[8 * EKF_N + (j)]}

/* A P over A's nonzero columns only: a position row is P's row plus columns 3..8 (velocity and attitude),
 * a velocity row columns 3..8, an attitude row columns 6..8: 351 multiply-adds instead of 729. Three rows
 * of A at a time in registers, each column of P loaded once for the three. */
static void imu_ap(const float *P, const float A[EKF_N][EKF_N], float AP[EKF_N][EKF_N])
{
    float a0[6], a1[6], a2[6];
    int j;
    memcpy(a0, &A[0][EKF_PX], sizeof a0);
    memcpy(a1, &A[1][EKF_PX], sizeof a1);
    memcpy(a2, &A[2][EKF_PX], sizeof a2);
    for (j = 0; j < EKF_N; j++) {
        const float v[6] = COL6(P, j);
        AP[0][j] = row6(P[j], a0, v);
        AP[1][j] = row6(P[EKF_N + j], a1, v);
        AP[2][j] = row6(P[2 * EKF_N + j], a2, v);
    }
    memcpy(a0, &A[EKF_PX][EKF_PX], sizeof a0);
    memcpy(a1, &A[EKF_PY][EKF_PX], sizeof a1);
    memcpy(a2, &A[EKF_PZ][EKF_PX], sizeof a2);
    for (j = 0; j < EKF_N; j++) {
        const float v[6] = COL6(P, j);
        AP[EKF_PX][j] = row6z(a0, v);
        AP[EKF_PY][j] = row6z(a1, v);
        AP[EKF_PZ][j] = row6z(a2, v);
    }
    memcpy(a0, &A[EKF_D0][EKF_D0], 3 * sizeof a0[0]);
    memcpy(a1, &A[EKF_D1][EKF_D0], 3 * sizeof a1[0]);
    memcpy(a2, &A[EKF_D2][EKF_D0], 3 * sizeof a2[0]);
    for (j = 0; j < EKF_N; j++) {
        const float v[3] = {P[EKF_D0 * EKF_N + j], P[EKF_D1 * EKF_N + j], P[EKF_D2 * EKF_N + j]};
        AP[EKF_D0][j] = row3z(a0, v);
        AP[EKF_D1][j] = row3z(a1, v);
        AP[EKF_D2][j] = row3z(a2, v);
    }
}

/* P = A P A^T: (A P) A^T over A's nonzero columns (333 multiply-adds instead of 729), three columns at a
 * time (A's rows in registers, each row of A P loaded once for the three). Both triangles: the clamp averages
 * P_ij and P_ji as before (computing one triangle only is cheaper still, but the rounding then differs from
 * the twin's by up to 4 mm after a divergence, test_supervisor_matches_twin). */
static void imu_propagate_cov(ekf_t *ekf, const float A[EKF_N][EKF_N])
{
    float AP[EKF_N][EKF_N], a0[6], a1[6], a2[6];
    float *P = &ekf->P[0][0];
    int i;
    imu_ap(P, A, AP);
    memcpy(a0, &A[0][EKF_PX], sizeof a0);
    memcpy(a1, &A[1][EKF_PX], sizeof a1);
    memcpy(a2, &A[2][EKF_PX], sizeof a2);
    for (i = 0; i < EKF_N; i++) {
        float *row = P + i * EKF_N;
        const float v[6] = {AP[i][3], AP[i][4], AP[i][5], AP[i][6], AP[i][7], AP[i][8]};
        row[0] = row6(AP[i][0], a0, v);
        row[1] = row6(AP[i][1], a1, v);
        row[2] = row6(AP[i][2], a2, v);
    }
    memcpy(a0, &A[EKF_PX][EKF_PX], sizeof a0);
    memcpy(a1, &A[EKF_PY][EKF_PX], sizeof a1);
    memcpy(a2, &A[EKF_PZ][EKF_PX], sizeof a2);
    for (i = 0; i < EKF_N; i++) {
        float *row = P + i * EKF_N;
        const float v[6] = {AP[i][3], AP[i][4], AP[i][5], AP[i][6], AP[i][7], AP[i][8]};
        row[EKF_PX] = row6z(a0, v);
        row[EKF_PY] = row6z(a1, v);
        row[EKF_PZ] = row6z(a2, v);
    }
    memcpy(a0, &A[EKF_D0][EKF_D0], 3 * sizeof a0[0]);
    memcpy(a1, &A[EKF_D1][EKF_D0], 3 * sizeof a1[0]);
    memcpy(a2, &A[EKF_D2][EKF_D0], 3 * sizeof a2[0]);
    for (i = 0; i < EKF_N; i++) {
        float *row = P + i * EKF_N;
        const float v[3] = {AP[i][6], AP[i][7], AP[i][8]};
        row[EKF_D0] = row3z(a0, v);
        row[EKF_D1] = row3z(a1, v);
        row[EKF_D2] = row3z(a2, v);
    }
}

/* Process noise (see the file comment), with the R of the start of the step. */
static void imu_process_noise(ekf_t *ekf, const ekf_noise_t *noise, float dt)
{
    const float (*R)[3] = (const float (*)[3])ekf->R;
    const float dt2 = dt * dt, half_dt2 = dt2 * 0.5f; /* x dt2 0.5 = x half_dt2: the halving is exact */
    float Sa[3], RS[3][3];
    int i, j;
    Sa[0] = noise->acc_xy * noise->acc_xy;
    Sa[1] = Sa[0];
    Sa[2] = noise->acc_z * noise->acc_z;
    for (i = 0; i < 3; i++) {
        RS[i][0] = R[i][0] * Sa[0]; /* (R Sa)_ij, the first product of each term below */
        RS[i][1] = R[i][1] * Sa[1];
        RS[i][2] = R[i][2] * Sa[2];
    }
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++) {
            /* (R Sa R^T)_ij and (R Sa)_ij */
            float rsr = RS[i][0] * R[j][0] + RS[i][1] * R[j][1] + RS[i][2] * R[j][2];
            float pv = RS[i][j] * half_dt2;
            ekf->P[i][j] += rsr * dt2 * dt * (1.0f / 3.0f);
            ekf->P[i][EKF_PX + j] += pv;
            ekf->P[EKF_PX + j][i] += pv;
        }
        ekf->P[EKF_PX + i][EKF_PX + i] += Sa[i] * dt;
    }
    ekf->P[EKF_D0][EKF_D0] += EKF_GYRO_NOISE_RP * EKF_GYRO_NOISE_RP * dt;
    ekf->P[EKF_D1][EKF_D1] += EKF_GYRO_NOISE_RP * EKF_GYRO_NOISE_RP * dt;
    ekf->P[EKF_D2][EKF_D2] += EKF_GYRO_NOISE_YAW * EKF_GYRO_NOISE_YAW * dt;
}

/* Nominal state: full accelerometer (specific force), body-frame velocity. */
static void imu_nominal_step(ekf_t *ekf, const float acc[3], const float gyro[3], float dt)
{
    float (*R)[3] = ekf->R;
    float *x = ekf->x;
    const float px = x[EKF_PX], py = x[EKF_PY], pz = x[EKF_PZ];
    const float wx = gyro[0], wy = gyro[1], wz = gyro[2];
    const float dt2 = dt * dt;
    float dpos[3], rot[3];
    int i;
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
}

void ekf_predict_imu(ekf_t *ekf, const ekf_noise_t *noise, const float acc[3], const float gyro[3],
                     float dt)
{
    float A[EKF_N][EKF_N];
    imu_transition(ekf, gyro, dt, A);
    imu_propagate_cov(ekf, (const float (*)[EKF_N])A);
    imu_process_noise(ekf, noise, dt);
    imu_nominal_step(ekf, acc, gyro, dt);
    ekf_sym_clamp_flat(&ekf->P[0][0]);
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
    if (ekf_imu_due(ekf, t_us)) {
        const float inv = 1.0f / (float)ekf->imu_count;
        const float dt = uwb_u64_to_float(t_us - ekf->t_us) * 1e-6f;
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
    ekf_sym_clamp_flat(&ekf->P[0][0]);
}
