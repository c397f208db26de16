/* ekf_core: scalar update against hand-computed numbers and a plain 9x9 Joseph reference,
 * symmetry/PSD, clamping, finalize, externalize. The predictions are in test_ekf_predict.c. */
#include <float.h>
#include <stdio.h>
#include <string.h>

#include "ekf_core.h"
#include "ekf_fixture.h"
#include "unit.h"

static const float origin[3] = {0.0f, 0.0f, 0.0f};
static const ekf_noise_t no_noise = {0.0f, 0.0f};

/* Plain Joseph form in double with full matrices: the reference for the structured version. */
static void joseph_reference(const float P[EKF_N][EKF_N], const float h[3], float y, float r,
                             double x_out[EKF_N], double P_out[EKF_N][EKF_N])
{
    double H[EKF_N] = {0}, PH[EKF_N], K[EKF_N], M[EKF_N][EKF_N], MP[EKF_N][EKF_N], S = r;
    int i, j, k;
    H[0] = h[0];
    H[1] = h[1];
    H[2] = h[2];
    for (i = 0; i < EKF_N; i++) {
        PH[i] = 0.0;
        for (k = 0; k < EKF_N; k++) {
            PH[i] += P[i][k] * H[k];
        }
    }
    for (i = 0; i < EKF_N; i++) {
        S += H[i] * PH[i];
    }
    for (i = 0; i < EKF_N; i++) {
        K[i] = PH[i] / S;
        x_out[i] = K[i] * y;
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            M[i][j] = (i == j) - K[i] * H[j];
        }
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            MP[i][j] = 0.0;
            for (k = 0; k < EKF_N; k++) {
                MP[i][j] += M[i][k] * P[k][j];
            }
        }
    }
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            double s = r * K[i] * K[j];
            for (k = 0; k < EKF_N; k++) {
                s += MP[i][k] * M[j][k];
            }
            P_out[i][j] = s;
        }
    }
}

static void test_scalar_update_hand_computed(void)
{
    /* P = diag(1, 2, 3, .5, .5, .5, 1e-4 ...) with P[0][3] = 0.2; H = [0.6 0.8 0 ...]; y = 0.5,
     * R = 0.25:  P H^T = (0.6, 1.6, 0, 0.12, 0 ...), S = 0.36 + 1.28 + 0.25 = 1.89. */
    ekf_t e;
    ekf_scalar_t m;
    const float h[3] = {0.6f, 0.8f, 0.0f};
    ekf_init(&e, origin, 1.0f, 1.0f);
    e.P[1][1] = 2.0f;
    e.P[2][2] = 3.0f;
    e.P[EKF_PX][EKF_PX] = e.P[EKF_PY][EKF_PY] = e.P[EKF_PZ][EKF_PZ] = 0.5f;
    e.P[0][EKF_PX] = e.P[EKF_PX][0] = 0.2f;
    ekf_scalar_prepare(&e, &m, h, 0.5f, 0.25f);
    CHECK_NEAR(m.S, 1.89, 1e-6);
    CHECK_NEAR(m.mahalanobis, 0.5 / sqrt(1.89), 1e-6);
    CHECK_NEAR(m.ph[3], 0.12, 1e-7);
    ekf_scalar_apply(&e, &m);
    CHECK_NEAR(m.K[0], 0.6 / 1.89, 1e-6);
    CHECK_NEAR(m.K[1], 1.6 / 1.89, 1e-6);
    CHECK_NEAR(m.K[2], 0.0, 1e-9);
    CHECK_NEAR(m.K[3], 0.12 / 1.89, 1e-6);
    CHECK_NEAR(e.x[0], 0.5 * 0.6 / 1.89, 1e-6);
    CHECK_NEAR(e.x[1], 0.5 * 1.6 / 1.89, 1e-6);
    CHECK_NEAR(e.x[EKF_PX], 0.5 * 0.12 / 1.89, 1e-6);
    /* optimal gain: Joseph == P - P H^T H P / S */
    CHECK_NEAR(e.P[0][0], 1.0 - 0.36 / 1.89, 1e-6);
    CHECK_NEAR(e.P[0][1], -0.96 / 1.89, 1e-6);
    CHECK_NEAR(e.P[1][1], 2.0 - 2.56 / 1.89, 1e-6);
    CHECK_NEAR(e.P[2][2], 3.0, 1e-6);
    CHECK_NEAR(e.P[0][EKF_PX], 0.2 - 0.6 * 0.12 / 1.89, 1e-6);
    CHECK_NEAR(e.P[EKF_PX][EKF_PX], 0.5 - 0.0144 / 1.89, 1e-6);
    CHECK_NEAR(e.P[EKF_D0][EKF_D0], 1e-4, 1e-9);
}

static void test_scalar_update_matches_full_joseph(void)
{
    int trial, i, j;
    for (trial = 0; trial < 50; trial++) {
        ekf_t e;
        ekf_scalar_t m;
        double x_ref[EKF_N], P_ref[EKF_N][EKF_N];
        const float h[3] = {(float)rnd(), (float)rnd(), (float)rnd()};
        const float y = (float)rnd(), r = 0.01f + 0.1f * (float)(rnd() + 1.0);
        double err = 0.0;
        ekf_init(&e, origin, 1.0f, 1.0f);
        random_spd(e.P);
        joseph_reference(e.P, h, y, r, x_ref, P_ref);
        ekf_scalar_update(&e, &m, h, y, r);
        for (i = 0; i < EKF_N; i++) {
            err = fmax(err, fabs(e.x[i] - x_ref[i]));
            for (j = 0; j < EKF_N; j++) {
                err = fmax(err, fabs(e.P[i][j] - P_ref[i][j]));
            }
        }
        CHECK(err < 2e-5);
    }
}

/* The update and the finalize step bound P on their way (the clamp's usual path fused into their writes):
 * what they leave is a fixed point of the full clamp, bit for bit, in range and with variances above P_MAX. */
static void test_update_and_finalize_leave_p_clamped(void)
{
    int trial;
    for (trial = 0; trial < 40; trial++) {
        ekf_t e;
        ekf_scalar_t m;
        float before[EKF_N][EKF_N];
        const float h[3] = {(float)rnd(), (float)rnd(), (float)rnd()};
        int i, j;
        ekf_init(&e, origin, 1.0f, 1.0f);
        random_spd(e.P);
        for (i = 0; i < EKF_N; i++) {
            for (j = 0; j < EKF_N; j++) {
                e.P[i][j] *= trial % 4 == 3 ? 400.0f : 1.0f; /* some variances beyond P_MAX: the general path */
            }
        }
        ekf_scalar_update(&e, &m, h, 0.3f * (float)rnd(), 1e-3f);
        CHECK(is_symmetric(e.P));
        memcpy(before, e.P, sizeof before);
        ekf_sym_clamp(e.P);
        CHECK(memcmp(before, e.P, sizeof before) == 0);
        e.x[EKF_D0 + trial % 3] = 0.2f * (float)rnd();
        ekf_finalize(&e);
        CHECK(is_symmetric(e.P));
        memcpy(before, e.P, sizeof before);
        ekf_sym_clamp(e.P);
        CHECK(memcmp(before, e.P, sizeof before) == 0);
    }
}

static void test_joseph_keeps_symmetric_pd(void)
{
    ekf_t e;
    ekf_scalar_t m;
    int k, i;
    ekf_init(&e, origin, 1.0f, 1.0f);
    random_spd(e.P);
    /* many precise measurements along few directions drive P towards singular */
    for (k = 0; k < 2000; k++) {
        const float h[3] = {(float)rnd(), (float)rnd(), 0.1f * (float)rnd()};
        ekf_scalar_update(&e, &m, h, (float)rnd() * 0.01f, 1e-4f);
        CHECK(is_symmetric(e.P));
        for (i = 0; i < EKF_N; i++) {
            CHECK(e.P[i][i] >= EKF_P_MIN);
        }
        if (!is_pd(e.P)) {
            CHECK(0);
            break;
        }
    }
    CHECK(ekf_is_finite(&e));
}

static void test_sym_clamp(void)
{
    float P[EKF_N][EKF_N];
    memset(P, 0, sizeof P);
    P[0][1] = 1.0f;
    P[1][0] = 3.0f;
    P[2][3] = NAN;
    P[4][5] = 1e9f;
    P[5][4] = 1e9f;
    P[6][7] = -1e9f;
    P[7][6] = -1e9f;
    P[8][8] = -5.0f;
    P[3][3] = INFINITY;
    ekf_sym_clamp(P);
    CHECK(P[0][1] == 2.0f && P[1][0] == 2.0f);
    /* row 3 has a non-finite variance: it loses its correlations (the NaN too) */
    CHECK(P[2][3] == 0.0f && P[3][2] == 0.0f);
    CHECK(P[4][5] == EKF_P_MAX);
    CHECK(P[6][7] == -EKF_P_MAX);
    CHECK(P[8][8] == EKF_P_MIN && P[0][0] == EKF_P_MIN);
    CHECK(P[3][3] == EKF_P_MAX);
}

/* Regression (rcv_twr sequence 3): clamping a large variance entry by entry left P indefinite
 * (a variance cut to 100 next to an uncut covariance), S went negative and an update threw
 * the state 1e5 m away. Scaling the row and column keeps P positive definite and the correlation. */
static void test_sym_clamp_keeps_pd(void)
{
    float P[EKF_N][EKF_N];
    int i;
    memset(P, 0, sizeof P);
    for (i = 0; i < EKF_N; i++) {
        P[i][i] = 1.0f;
    }
    P[2][2] = 1000.0f;
    P[5][5] = 400.0f;
    P[2][5] = P[5][2] = 400.0f;   /* correlation 0.632 */
    P[0][2] = P[2][0] = 20.0f;
    CHECK(is_pd(P));
    ekf_sym_clamp(P);
    CHECK(is_pd(P));
    CHECK_NEAR(P[2][2], EKF_P_MAX, 1e-3);
    CHECK_NEAR(P[5][5], EKF_P_MAX, 1e-3);
    CHECK_NEAR(P[2][5] / sqrtf(P[2][2] * P[5][5]), 400.0 / sqrt(1000.0 * 400.0), 1e-5);
    CHECK_NEAR(P[0][2], 20.0 * sqrt(100.0 / 1000.0), 1e-4);
    CHECK(P[0][0] == 1.0f);
}

static void test_finalize_moves_attitude_error_into_q(void)
{
    ekf_t e;
    ekf_state_t s;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    ekf_init(&e, p0, 1.0f, 1.0f);
    e.P[EKF_PX][EKF_D2] = e.P[EKF_D2][EKF_PX] = 1e-5f;
    e.x[EKF_D2] = 0.1f;
    ekf_finalize(&e);
    ekf_externalize(&e, &s);
    CHECK(e.x[EKF_D0] == 0.0f && e.x[EKF_D1] == 0.0f && e.x[EKF_D2] == 0.0f);
    CHECK_NEAR(s.rpy[2], 0.1, 1e-6);
    CHECK_NEAR(s.quat[0] * s.quat[0] + s.quat[3] * s.quat[3], 1.0, 1e-6);
    /* G for d = (0, 0, 0.05): rows D0/D1 rotate by +-0.05, D2 keeps 1 - 0 */
    CHECK_NEAR(e.P[EKF_PX][EKF_D2], 1e-5, 1e-9);
    CHECK_NEAR(e.P[EKF_D0][EKF_D0], 1e-4 * ((1 - 0.05 * 0.05 / 2) * (1 - 0.05 * 0.05 / 2) + 0.05 * 0.05), 1e-9);
    CHECK(is_symmetric(e.P));
    /* an absurd attitude error is dropped, not applied */
    e.x[EKF_D0] = 20.0f;
    ekf_finalize(&e);
    ekf_externalize(&e, &s);
    CHECK_NEAR(s.rpy[2], 0.1, 1e-6);
    CHECK(e.x[EKF_D0] == 0.0f);
}

static void test_externalize_world_velocity_and_rpy(void)
{
    ekf_t e;
    ekf_state_t s;
    const float acc[3] = {0.0f, 0.0f, EKF_GRAVITY}, spin[3] = {0.0f, 0.0f, 50.0f};
    ekf_init(&e, origin, 1.0f, 1.0f);
    ekf_predict_imu(&e, &no_noise, acc, spin, 0.01f); /* yaw 0.5 rad, still at rest */
    e.x[EKF_PX] = 1.0f;
    ekf_externalize(&e, &s);
    CHECK_NEAR(s.vel_world[0], cos(0.5), 1e-5);
    CHECK_NEAR(s.vel_world[1], sin(0.5), 1e-5);
    CHECK_NEAR(s.rpy[2], 0.5, 1e-5);
    CHECK(s.var[0] == e.P[0][0] && s.var[8] == e.P[8][8]);
    {
        /* pure pitch of 0.3 rad and roll of -0.2 rad */
        float rpy[3];
        const float qp[4] = {(float)cos(0.15), 0.0f, (float)sin(0.15), 0.0f};
        const float qr[4] = {(float)cos(-0.1), (float)sin(-0.1), 0.0f, 0.0f};
        ekf_quat_to_rpy(qp, rpy);
        CHECK_NEAR(rpy[1], 0.3, 1e-6);
        ekf_quat_to_rpy(qr, rpy);
        CHECK_NEAR(rpy[0], -0.2, 1e-6);
    }
}

/* ekf_quat_to_rpy's own atan2 (no libm atan2f/asinf): within 3 ulp of the double-precision angles of the same
 * float arguments over random attitudes, signed zeros and NaN as atan2. */
static void test_quat_to_rpy_angles_within_three_ulp(void)
{
    double worst = 0.0;
    int k, a;
    for (k = 0; k < 200000; k++) {
        float q[4], rpy[3], n = 0.0f, sp;
        double ref[3];
        for (a = 0; a < 4; a++) {
            q[a] = (float)rnd();
            n += q[a] * q[a];
        }
        for (a = 0; a < 4; a++) {
            q[a] /= sqrtf(n);
        }
        if (k % 7 == 0) { /* near level as in flight: small roll and pitch */
            q[1] *= 1e-3f;
            q[2] *= 1e-3f;
        }
        ekf_quat_to_rpy(q, rpy);
        sp = 2.0f * (q[0] * q[2] - q[3] * q[1]);
        sp = sp > 1.0f ? 1.0f : (sp < -1.0f ? -1.0f : sp);
        ref[0] = atan2(2.0f * (q[0] * q[1] + q[2] * q[3]), 1.0f - 2.0f * (q[1] * q[1] + q[2] * q[2]));
        ref[1] = asin(sp);
        ref[2] = atan2(2.0f * (q[0] * q[3] + q[1] * q[2]), 1.0f - 2.0f * (q[2] * q[2] + q[3] * q[3]));
        for (a = 0; a < 3; a++) {
            const double ulp = fmax(ldexp(1.0, ilogb(fabs(ref[a])) - 23), 1e-45);
            worst = fmax(worst, fabs(rpy[a] - ref[a]) / ulp);
        }
    }
    printf("  (max error %.2f ulp)\n", worst);
    CHECK(worst <= 3.0);
    {
        float rpy[3];
        const float level[4] = {1.0f, 0.0f, 0.0f, 0.0f}, flip[4] = {0.0f, 1.0f, 0.0f, 0.0f};
        const float bad[4] = {NAN, 0.0f, 0.0f, 0.0f};
        ekf_quat_to_rpy(level, rpy);
        CHECK(rpy[0] == 0.0f && rpy[1] == 0.0f && rpy[2] == 0.0f && !signbit(rpy[0]));
        ekf_quat_to_rpy(flip, rpy); /* roll = atan2(+0, -1) = pi */
        CHECK_NEAR(rpy[0], 3.14159265358979, 3e-7);
        ekf_quat_to_rpy(bad, rpy);
        CHECK(isnan(rpy[0]) && isnan(rpy[2]));
    }
}

static void test_is_finite(void)
{
    ekf_t e;
    ekf_init(&e, origin, 1.0f, 1.0f);
    CHECK(ekf_is_finite(&e));
    e.x[4] = NAN;
    CHECK(!ekf_is_finite(&e));
    CHECK(!ekf_state_finite(&e));
    e.x[4] = 0.0f;
    e.q[2] = INFINITY;
    CHECK(!ekf_is_finite(&e));
    CHECK(!ekf_state_finite(&e));
    e.q[2] = 0.0f;
    CHECK(ekf_state_finite(&e));
    e.P[3][3] = NAN; /* not looked at: the clamp never leaves one */
    CHECK(ekf_state_finite(&e) && !ekf_is_finite(&e));
}

/* The integer forms of the clamp's tests agree with the float compares they replace (ekf_core.h). */
static void test_clamp_bit_tests_match_float_compares(void)
{
    const float vals[] = {0.0f, -0.0f, 1e-7f, 9.99e-7f, EKF_P_MIN, 1.01e-6f, 0.5f, 99.999f, EKF_P_MAX, 100.001f,
                          -1e-7f, -0.5f, -EKF_P_MAX, -100.001f, 1e30f, -1e30f, 1e-40f, -1e-40f,
                          INFINITY, -INFINITY, NAN};
    size_t k;
    CHECK(ekf_f32_bits(EKF_P_MAX) == EKF_P_MAX_BITS);
    CHECK(ekf_f32_bits(EKF_P_MIN) == EKF_P_MIN_BITS);
    for (k = 0; k < sizeof vals / sizeof vals[0]; k++) {
        const float v = vals[k];
        CHECK(ekf_var_in_range(v) == (fabsf(v) <= EKF_P_MAX));
        if (v == v) {
            const float want = v < EKF_P_MIN ? EKF_P_MIN : v;
            CHECK(ekf_f32_bits(ekf_var_floor(v)) == ekf_f32_bits(want));
        }
        if (fabsf(v) <= EKF_P_MAX) {
            CHECK(ekf_f32_bits(ekf_clamp_cov(v)) == ekf_f32_bits(v));
        } else {
            CHECK(ekf_clamp_cov(v) == (v != v ? 0.0f : (v > 0.0f ? EKF_P_MAX : -EKF_P_MAX)));
        }
    }
}

int main(void)
{
    RUN(test_scalar_update_hand_computed);
    RUN(test_scalar_update_matches_full_joseph);
    RUN(test_joseph_keeps_symmetric_pd);
    RUN(test_update_and_finalize_leave_p_clamped);
    RUN(test_sym_clamp);
    RUN(test_clamp_bit_tests_match_float_compares);
    RUN(test_sym_clamp_keeps_pd);
    RUN(test_finalize_moves_attitude_error_into_q);
    RUN(test_quat_to_rpy_angles_within_three_ulp);
    RUN(test_externalize_world_velocity_and_rpy);
    RUN(test_is_finite);
    return UNIT_DONE();
}
