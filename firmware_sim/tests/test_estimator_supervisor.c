/* estimator: the divergence guard and the supervisor's bounds (box, speed, covariance, gaps). */
#include <float.h>

#include "estimator_fixture.h"

static void test_divergence_guard(void)
{
    estimator_result_t r;
    float pos[3], vel[3], quat[4], var[9];
    const float truth[3] = {0.5f, 0.5f, 1.0f};
    const float huge_acc[3] = {FLT_MAX, 0.0f, EKF_GRAVITY};
    uint64_t t;
    setup(EST_MODE_IMU, 0, truth[0], truth[1], truth[2]);
    run_static(truth, 1);
    CHECK(est.divergences == 0);
    /* IMU samples whose sum overflows: the prediction makes the state infinite */
    for (t = 1001000; t <= 1010000; t += 1000) {
        CHECK(estimator_on_imu(&est, t, huge_acc, no_gyro) == EST_OK);
    }
    CHECK(est.divergences == 1);
    estimator_state(&est, pos, vel, quat, var);
    CHECK_NEAR(pos[0], truth[0], 0.01);
    CHECK_NEAR(pos[1], truth[1], 0.01);
    CHECK_NEAR(pos[2], truth[2], 0.01);
    CHECK(vel[0] == 0.0f && quat[0] == 1.0f);
    CHECK(var[0] == est.cfg.init_std_xy * est.cfg.init_std_xy && var[2] == est.cfg.init_std_z * est.cfg.init_std_z);
    CHECK(est.ekf.t_us == 1010000); /* the time reference survives */
    /* an absurd range (no gates) throws the position out of any network: back again */
    CHECK(estimator_on_twr(&est, 1010000, 0, FLT_MAX, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    CHECK(est.divergences == 2);
    estimator_state(&est, pos, vel, quat, var);
    CHECK_NEAR(pos[0], truth[0], 0.01);
    CHECK(isfinite(pos[0]) && isfinite(var[0]));
    /* and the filter carries on */
    for (t = 1011000; t <= 3000000; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
        if (t % 10000 == 5000) {
            uint8_t k = (uint8_t)((t / 10000) % 8);
            CHECK(estimator_on_twr(&est, t, k, range_to(&est, k, truth), &r) == EST_OK);
        }
    }
    estimator_state(&est, pos, vel, quat, var);
    CHECK_NEAR(pos[0], truth[0], 0.005);
    CHECK_NEAR(pos[2], truth[2], 0.005);
    CHECK(est.divergences == 2);
}

/* The supervisor: each bound re-initialises the filter at the last position that passed and reports
 * the reason in the next result's flags. Here the box (and its margin) and the speed. */
static void test_supervisor_box_and_speed(void)
{
    estimator_result_t r;
    float pos[3], vel[3], var[9];
    const float p0[3] = {0.5f, 0.5f, 1.0f};
    uint64_t t = 0;
    uint8_t k;
    /* out of the box: a range that (no gates) pulls the tag ~30 m beyond the anchors (x 3.5 + 10) */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    est.cfg.std_twr = 1e-3f; /* the update follows the measurement */
    for (k = 0; k < 8; k++, t += 5000) {
        CHECK(estimator_on_twr(&est, t, k, range_to(&est, k, p0), &r) == EST_OK);
        CHECK(r.flags == 0);
    }
    CHECK(est.divergences == 0);
    CHECK(estimator_on_twr(&est, t, 0, 40.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    CHECK(r.flags == (EST_FLAG_DIVERGED | EST_FLAG_OUT_OF_BOX));
    CHECK(est.divergences == 1);
    estimator_state(&est, pos, vel, NULL, var);
    CHECK_NEAR(pos[0], p0[0], 0.05);
    CHECK_NEAR(pos[2], p0[2], 0.05);
    CHECK(vel[0] == 0.0f && var[0] == 1.0f);
    CHECK(estimator_on_twr(&est, t + 5000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(r.flags == 0); /* reported once */
    /* the margin is configurable: 30 m lets the same jump through */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    est.cfg.std_twr = 1e-3f;
    est.cfg.sup_margin = 30.0f;
    CHECK(estimator_on_twr(&est, 0, 0, 40.0f, &r) == EST_OK);
    CHECK(r.flags == 0 && est.divergences == 0);
    /* speed: ranges that move 1 m per 5 ms build a velocity above 10 m/s */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    est.cfg.sup_margin = 1000.0f;
    est.cfg.std_twr = 1e-3f;
    for (k = 0, t = 0; k < 200 && est.divergences == 0; k++, t += 5000) {
        const float moving[3] = {p0[0] + 0.1f * (float)k, p0[1], p0[2]};
        CHECK(estimator_on_twr(&est, t, (uint8_t)(k % 8), range_to(&est, (uint8_t)(k % 8), moving), &r) == EST_OK);
    }
    CHECK(est.divergences == 1);
    CHECK(r.flags == (EST_FLAG_DIVERGED | EST_FLAG_SPEED));
}

/* The covariance bound: a divergence while measurements arrive, a gap restart after an outage (UWB-only and
 * IMU modes); a huge initial std alone does not trip it. */
static void test_supervisor_covariance_and_gaps(void)
{
    estimator_result_t r;
    float pos[3], vel[3], var[9];
    const float p0[3] = {0.5f, 0.5f, 1.0f};
    uint64_t t;
    /* covariance while measurements arrive: ranges to one anchor only every 10 ms leave the directions
     * across it unobserved, their variance grows (q = 2 m/s^2) past the bound: a divergence */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    for (t = 0; t <= 20000000 && est.divergences == 0; t += 10000) {
        CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0), &r) == EST_OK);
    }
    CHECK(est.divergences == 1 && est.gap_restarts == 0);
    CHECK(r.flags == (EST_FLAG_DIVERGED | EST_FLAG_COVARIANCE));
    /* the same bound after a 10 s outage (var_p grows to the clamp without a measurement): a restart
     * from the last fix, reported as a gap, not a divergence */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    CHECK(estimator_on_twr(&est, 0, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK(estimator_on_twr(&est, 999000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(r.flags == 0); /* under a second: no gap, and the bound holds */
    CHECK(estimator_on_twr(&est, 10999000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(r.flags == EST_FLAG_GAP_RESTART);
    CHECK(est.divergences == 0 && est.gap_restarts == 1);
    estimator_state(&est, pos, vel, NULL, var);
    CHECK_NEAR(pos[0], p0[0], 0.05);
    /* restarted with half the bound (50) as position variance, this range fused along one direction */
    CHECK(vel[0] == 0.0f && var[0] <= 25.0f && var[1] <= 25.0f && var[2] <= 25.0f);
    CHECK(var[0] + var[1] + var[2] > 40.0f);
    /* IMU mode: the covariance grows from IMU predictions during an outage: a gap too */
    setup(EST_MODE_IMU, 0, p0[0], p0[1], p0[2]);
    est.cfg.sup_max_var = 2.0f; /* twice the initial variance: reached within seconds */
    CHECK(estimator_on_twr(&est, 0, 0, range_to(&est, 0, p0), &r) == EST_OK);
    for (t = 1000; t <= 30000000 && est.gap_restarts == 0; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
    }
    CHECK(est.gap_restarts >= 1 && est.divergences == 0);
    /* a huge initial std is valid and does not trip the covariance bound by itself */
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], p0[2]);
    est.cfg.init_std_xy = 1e20f;
    CHECK(estimator_on_twr(&est, 0, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK(estimator_on_twr(&est, 5000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(est.divergences == 0);
}

int main(void)
{
    RUN(test_divergence_guard);
    RUN(test_supervisor_box_and_speed);
    RUN(test_supervisor_covariance_and_gaps);
    return UNIT_DONE();
}
