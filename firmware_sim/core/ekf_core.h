/* Error-state EKF core (Crazyflie-style): 9 error states, separately stored attitude quaternion,
 * 100 Hz IMU prediction or constant-velocity prediction, sequential scalar updates in Joseph form.
 * OS-free C99, no allocation, single precision; the numpy twin (harness/twin/ekf.py) mirrors it. */
#ifndef UWB_EKF_CORE_H
#define UWB_EKF_CORE_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#define EKF_N 9

/* Error-state indices: world position, BODY-frame velocity, attitude error (rotation vector). */
enum { EKF_X = 0, EKF_Y, EKF_Z, EKF_PX, EKF_PY, EKF_PZ, EKF_D0, EKF_D1, EKF_D2 };

#define EKF_GRAVITY 9.81f                /* m/s^2, same constant as the Crazyflie */
#define EKF_P_MIN 1e-6f                  /* covariance diagonal floor */
#define EKF_P_MAX 100.0f                 /* covariance magnitude bound; NaN is replaced by this */
#define EKF_PREDICT_INTERVAL_US 10000u   /* IMU mode: predict at 100 Hz */
#define EKF_INIT_STD_VEL 0.5f            /* m/s: initial velocity std (the tag may already move) */
#define EKF_INIT_STD_ATT 0.01f           /* rad: initial roll/pitch/yaw std */

typedef struct {
    float x[EKF_N];          /* error state (EKF_X..EKF_D2); x[D0..D2] is zero outside an update */
    float q[4];              /* attitude (w, x, y, z), body -> world */
    float R[3][3];           /* rotation matrix of q, body -> world */
    float P[EKF_N][EKF_N];   /* covariance of the error state */
    float acc_sum[3];        /* IMU samples summed since the last prediction */
    float gyro_sum[3];
    uint32_t imu_count;
    uint64_t t_us;           /* IMU mode: time of the last prediction; UWB-only: state time */
    uint8_t has_time;        /* t_us is valid */
} ekf_t;

/* Process noise of the IMU-mode prediction (white acceleration, body frame, m/s^2/sqrt(Hz)). */
typedef struct {
    float acc_xy;
    float acc_z;
} ekf_noise_t;

/* Diagnostics of one scalar update (filterpy style): all exposed after ekf_scalar_prepare/apply. */
typedef struct {
    float h[3];          /* nonzero part of H (1x9): H = [h0 h1 h2 0 0 0 0 0 0] */
    float ph[EKF_N];     /* P H^T */
    float r_var;         /* measurement noise variance R */
    float innovation;    /* y = z - h(x) */
    float S;             /* innovation variance H P H^T + R */
    float mahalanobis;   /* |y| / sqrt(S) */
    float K[EKF_N];      /* Kalman gain P H^T / S (set by ekf_scalar_apply) */
} ekf_scalar_t;

/* Externalised state. */
typedef struct {
    float pos[3];
    float vel_world[3];
    float quat[4];
    float var[EKF_N];    /* covariance diagonal */
    float rpy[3];        /* roll, pitch, yaw [rad] */
} ekf_state_t;

/* Position pos, zero velocity, identity attitude, diagonal P; time unset, accumulators cleared. */
void ekf_init(ekf_t *ekf, const float pos[3], float std_xy, float std_z);

/* IMU mode. The first sample only sets the prediction time; later samples are summed and, once
 * t_us - t_last_predict >= 10 ms, a prediction with their average runs. Returns 1 if it did. */
int ekf_imu_sample(ekf_t *ekf, const ekf_noise_t *noise, uint64_t t_us, const float acc[3],
                   const float gyro[3]);

/* 1 if a sample at t_us makes ekf_imu_sample predict: the caller times only those (reading the cost counter
 * masks interrupts, which costs an emulator a return to its main loop, on every one of ~1,000 samples a second). */
static inline int ekf_imu_due(const ekf_t *ekf, uint64_t t_us)
{
    return ekf->has_time && t_us >= ekf->t_us && t_us - ekf->t_us >= EKF_PREDICT_INTERVAL_US;
}

/* One IMU-mode prediction over dt [s] with mean specific force acc and body rates gyro. */
void ekf_predict_imu(ekf_t *ekf, const ekf_noise_t *noise, const float acc[3], const float gyro[3],
                     float dt);

/* Constant-velocity prediction over dt [s] with white acceleration std q_acc (UWB-only mode). */
void ekf_predict_cv(ekf_t *ekf, float q_acc, float dt);

/* Scalar update with H = [h, 0...]: prepare computes P H^T, S and the Mahalanobis distance
 * (used by the gates), apply computes K, corrects the state and updates P in Joseph form. */
void ekf_scalar_prepare(const ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation,
                        float r_var);
void ekf_scalar_apply(ekf_t *ekf, ekf_scalar_t *m);
void ekf_scalar_update(ekf_t *ekf, ekf_scalar_t *m, const float h[3], float innovation, float r_var);

/* Move the attitude error into q, rotate P accordingly, zero the attitude error. P must be as the
 * covariance clamp leaves it (symmetric, bounded: right after ekf_scalar_apply), as every caller has it. */
void ekf_finalize(ekf_t *ekf);

/* A vehicle at rest (after a touchdown; UWB-only: on the floor): velocity zero and known, its covariance
 * rows and columns zeroed but for EKF_P_MIN on the diagonal; the position's covariance kept. */
void ekf_hold_at_rest(ekf_t *ekf);

/* P = (P + P^T) / 2; a variance above EKF_P_MAX scales its row and column down to it (keeps P positive
 * semi-definite); a non-finite variance becomes EKF_P_MAX without correlations; other NaN -> 0;
 * |P_ij| <= EKF_P_MAX, P_ii >= EKF_P_MIN. */
void ekf_sym_clamp(float P[EKF_N][EKF_N]);
/* The same on a flat row-major 9x9 array (the form ekf_core.c and ekf_update.c call: GCC 12 misreads the
 * bounds of an array parameter at some call sites, a false -Wstringop-overflow). */
void ekf_sym_clamp_flat(float *P);
/* The same for a symmetric P given by its upper triangle (j >= i; the lower one is not read): the result
 * of ekf_sym_clamp_flat on that symmetric matrix, both triangles written. */
void ekf_sym_clamp_upper(float *P);

/* The entry-wise bounds of the clamp's usual path (every variance finite and <= EKF_P_MAX, so no row is
 * scaled; ekf_core.c, ekf_update.c): a variance in range, one off-diagonal entry bounded (NaN -> 0). */
/* The tests below compare IEEE bit patterns as integers: the same results as the float compares (a finite
 * float's magnitude orders as its bits, inf and NaN above every finite one), the same instruction count on the
 * M4, and no VFP compare, which an emulator runs as helper calls (vabs, vcmpe: ~10 % of QEMU's time on a
 * replay, docs/qemu.md "Speed"). EKF_P_MAX_BITS / EKF_P_MIN_BITS are checked against the floats by
 * tests/test_ekf.c. */
#define EKF_P_MAX_BITS 0x42c80000u       /* 100.0f */
#define EKF_P_MIN_BITS 0x358637bdu       /* 1e-6f */

static inline uint32_t ekf_f32_bits(float v)
{
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    return u;
}

static inline int ekf_var_in_range(float d)
{
    return (ekf_f32_bits(d) & 0x7fffffffu) <= EKF_P_MAX_BITS; /* fabsf(d) <= EKF_P_MAX: 0 also for NaN, -inf */
}

/* max(d, EKF_P_MIN) for a d that is not NaN (d < EKF_P_MIN ? EKF_P_MIN : d): signed, a negative d is below. */
static inline float ekf_var_floor(float d)
{
    return (int32_t)ekf_f32_bits(d) < (int32_t)EKF_P_MIN_BITS ? EKF_P_MIN : d;
}

#if defined(__GNUC__)
#define EKF_COLD __attribute__((noinline, cold))
#else
#define EKF_COLD
#endif

/* An off-diagonal entry beyond the bound: +-EKF_P_MAX, NaN -> 0 (out of line: the rare case). */
EKF_COLD float ekf_clamp_cov_out(float v);

static inline float ekf_clamp_cov(float v)
{
    return ekf_var_in_range(v) ? v : ekf_clamp_cov_out(v); /* the usual case: one test, |v| <= EKF_P_MAX */
}

/* 1 if the state, q and the diagonal of P are all finite. */
int ekf_is_finite(const ekf_t *ekf);
/* 1 if the state and q are finite: ekf_is_finite for a P the covariance clamp has left (its variances are then
 * finite by construction: the supervisor's check after every prediction and update). */
int ekf_state_finite(const ekf_t *ekf);

void ekf_externalize(const ekf_t *ekf, ekf_state_t *out);

/* Roll, pitch, yaw [rad] of q (ARCHITECTURE.md formulas). */
void ekf_quat_to_rpy(const float q[4], float rpy[3]);

#endif
