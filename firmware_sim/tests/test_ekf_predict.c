/* ekf_core: IMU prediction (timing, covariance, exact integration, rotation) and the constant-velocity
 * prediction. */
#include <string.h>

#include "ekf_core.h"
#include "ekf_fixture.h"
#include "unit.h"

static const float origin[3] = {0.0f, 0.0f, 0.0f};
static const ekf_noise_t no_noise = {0.0f, 0.0f};

static void test_imu_timing(void)
{
    ekf_t e;
    const float acc[3] = {0.0f, 0.0f, EKF_GRAVITY}, gyro[3] = {0.0f, 0.0f, 0.0f};
    uint64_t t;
    int ran = 0;
    ekf_init(&e, origin, 1.0f, 1.0f);
    CHECK(ekf_imu_sample(&e, &no_noise, 5000, acc, gyro) == 0); /* first sample: time only */
    CHECK(e.has_time && e.t_us == 5000 && e.imu_count == 0);
    for (t = 6000; t < 15000; t += 1000) {
        ran += ekf_imu_sample(&e, &no_noise, t, acc, gyro);
    }
    CHECK(ran == 0 && e.imu_count == 9);
    CHECK(ekf_imu_sample(&e, &no_noise, 15000, acc, gyro) == 1);
    CHECK(e.t_us == 15000 && e.imu_count == 0);
    /* a gap: one prediction over the whole gap */
    CHECK(ekf_imu_sample(&e, &no_noise, 115000, acc, gyro) == 1);
    CHECK(e.t_us == 115000);
}

static void test_imu_prediction_covariance(void)
{
    /* Level and at rest: A couples position to velocity only (p = 0, R = I, w = 0). */
    ekf_t e;
    const ekf_noise_t noise = {0.5f, 1.0f};
    const float acc[3] = {0.0f, 0.0f, EKF_GRAVITY}, gyro[3] = {0.0f, 0.0f, 0.0f};
    const double dt = 0.01, v = EKF_INIT_STD_VEL * EKF_INIT_STD_VEL, a = EKF_INIT_STD_ATT * EKF_INIT_STD_ATT;
    const double g = EKF_GRAVITY;
    ekf_init(&e, origin, 1.0f, 2.0f);
    ekf_predict_imu(&e, &noise, acc, gyro, (float)dt);
    CHECK_NEAR(e.x[0], 0.0, 1e-7);
    CHECK_NEAR(e.x[2], 0.0, 1e-6);
    CHECK_NEAR(e.x[EKF_PZ], 0.0, 1e-6);
    /* P_xx = 1 + dt^2 v + q^2 dt^3/3;  P_x,vx = dt v + q^2 dt^2/2;  P_vx = v + g^2 dt^2 a + q^2 dt */
    CHECK_NEAR(e.P[0][0], 1.0 + dt * dt * v + 0.25 * dt * dt * dt / 3.0, 1e-6);
    CHECK_NEAR(e.P[2][2], 4.0 + dt * dt * v + 1.0 * dt * dt * dt / 3.0, 1e-6);
    CHECK_NEAR(e.P[0][EKF_PX], dt * v + 0.25 * dt * dt / 2.0, 1e-7);
    CHECK_NEAR(e.P[EKF_PX][EKF_PX], v + g * g * dt * dt * a + 0.25 * dt, 1e-6);
    CHECK_NEAR(e.P[EKF_PZ][EKF_PZ], v + 1.0 * dt, 1e-6);
    /* velocity <- attitude: vx <- d1 (g dt), vy <- d0 (-g dt) */
    CHECK_NEAR(e.P[EKF_PX][EKF_D1], g * dt * a, 1e-7);
    CHECK_NEAR(e.P[EKF_PY][EKF_D0], -g * dt * a, 1e-7);
    CHECK(is_symmetric(e.P));
}

static void test_imu_integration_exact_for_constant_acceleration(void)
{
    /* level, 1 m/s^2 along body x: after 1 s, v = 1 m/s and p = 0.5 m (exact with dt^2/2 terms) */
    ekf_t e;
    const float acc[3] = {1.0f, 0.0f, EKF_GRAVITY}, gyro[3] = {0.0f, 0.0f, 0.0f};
    int k;
    ekf_init(&e, origin, 1.0f, 1.0f);
    for (k = 0; k < 100; k++) {
        ekf_predict_imu(&e, &no_noise, acc, gyro, 0.01f);
    }
    CHECK_NEAR(e.x[EKF_PX], 1.0, 1e-5);
    CHECK_NEAR(e.x[0], 0.5, 1e-5);
    CHECK_NEAR(e.x[2], 0.0, 1e-5);
}

static void test_imu_rotation(void)
{
    /* 1 rad/s about body z for 1 s -> yaw 1 rad; the accelerometer must read R^T g e3 = g e3 */
    ekf_t e;
    ekf_state_t s;
    const float acc[3] = {0.0f, 0.0f, EKF_GRAVITY}, gyro[3] = {0.0f, 0.0f, 1.0f};
    int k;
    ekf_init(&e, origin, 1.0f, 1.0f);
    for (k = 0; k < 100; k++) {
        ekf_predict_imu(&e, &no_noise, acc, gyro, 0.01f);
    }
    ekf_externalize(&e, &s);
    CHECK_NEAR(s.rpy[2], 1.0, 1e-5);
    CHECK_NEAR(s.rpy[0], 0.0, 1e-6);
    CHECK_NEAR(s.quat[0], cos(0.5), 1e-5);
    CHECK_NEAR(s.quat[3], sin(0.5), 1e-5);
    CHECK_NEAR(s.pos[2], 0.0, 1e-5);
}

static void test_cv_prediction(void)
{
    ekf_t e;
    const double dt = 0.1, q2 = 4.0, v = EKF_INIT_STD_VEL * EKF_INIT_STD_VEL;
    const float p0[3] = {1.0f, 2.0f, 3.0f};
    ekf_init(&e, p0, 1.0f, 1.0f);
    e.x[EKF_PX] = 1.0f;
    e.x[EKF_PZ] = -2.0f;
    ekf_predict_cv(&e, 2.0f, (float)dt);
    CHECK_NEAR(e.x[0], 1.1, 1e-6);
    CHECK_NEAR(e.x[1], 2.0, 1e-6);
    CHECK_NEAR(e.x[2], 2.8, 1e-6);
    CHECK_NEAR(e.P[0][0], 1.0 + dt * dt * v + q2 * dt * dt * dt / 3.0, 1e-6);
    CHECK_NEAR(e.P[0][EKF_PX], dt * v + q2 * dt * dt / 2.0, 1e-6);
    CHECK_NEAR(e.P[EKF_PX][0], e.P[0][EKF_PX], 0.0);
    CHECK_NEAR(e.P[EKF_PX][EKF_PX], v + q2 * dt, 1e-6);
    CHECK_NEAR(e.P[0][1], 0.0, 0.0);
    CHECK_NEAR(e.P[EKF_D0][EKF_D0], EKF_INIT_STD_ATT * EKF_INIT_STD_ATT, 1e-9);
}

int main(void)
{
    RUN(test_imu_timing);
    RUN(test_imu_prediction_covariance);
    RUN(test_imu_integration_exact_for_constant_acceleration);
    RUN(test_imu_rotation);
    RUN(test_cv_prediction);
    return UNIT_DONE();
}
