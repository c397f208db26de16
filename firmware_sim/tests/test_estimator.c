/* estimator: config defaults/validation, anchors, time rules, static convergence, UWB-only tracking,
 * height pseudo-measurements, costs. The gates (test_estimator_gates.c), the bias network
 * (test_estimator_nn.c) and the divergence guard and supervisor (test_estimator_supervisor.c) have their own. */
#include <string.h>

#include "estimator_fixture.h"

/* ------------------------------------------------------------------------------------------ */

static void test_default_config(void)
{
    estimator_config_t c;
    memset(&c, 0, sizeof c); /* padding too: the struct is compared with memcmp below */
    estimator_default_config(&c);
    CHECK(estimator_config_valid(&c));
    CHECK(c.mode == EST_MODE_IMU && c.stages == EST_STAGES_ALL);
    /* nn_min_z: the network at every height at power-up (its out-of-range fade guards the ground) */
    CHECK(c.std_twr == 0.25f && c.std_tdoa == 0.15f && c.nn_min_z == -1.0f);
    estimator_init(&est, &no_model);
    CHECK(memcmp(&est.cfg, &c, sizeof c) == 0);
}

static void test_config_validation(void)
{
    estimator_config_t d, c;
    estimator_default_config(&d);
#define EXPECT_VALID(field, value, ok) do { c = d; c.field = value; CHECK(estimator_config_valid(&c) == (ok)); } while (0)
    EXPECT_VALID(mode, 1, 1);
    EXPECT_VALID(mode, 2, 1);
    EXPECT_VALID(mode, 3, 0);
    EXPECT_VALID(stages, 0, 1);
    EXPECT_VALID(stages, EST_STAGES_ALL | EST_STAGE_NN_STD | EST_STAGE_ROBUST_UPDATE | EST_STAGE_NN_MONITOR |
                             EST_STAGE_BIAS_STATES, 1);
    EXPECT_VALID(stages, 128, 0);
    EXPECT_VALID(std_twr, 0.0f, 0);
    EXPECT_VALID(std_twr, -0.1f, 0);
    EXPECT_VALID(std_tdoa, NAN, 0);
    EXPECT_VALID(a_max_twr, 0.0f, 0);
    EXPECT_VALID(a_max_tdoa, INFINITY, 0);
    EXPECT_VALID(gate_dt_min, 0.0f, 0);
    EXPECT_VALID(chi2_twr, -1.0f, 0);
    EXPECT_VALID(chi2_tdoa, 0.0f, 0);
    EXPECT_VALID(proc_acc_xy, 0.0f, 1);
    EXPECT_VALID(proc_acc_xy, -0.1f, 0);
    EXPECT_VALID(proc_acc_z, -0.1f, 0);
    EXPECT_VALID(proc_cv_acc, 0.0f, 0);
    EXPECT_VALID(init_x, -1e3f, 1);
    EXPECT_VALID(init_y, NAN, 0);
    EXPECT_VALID(init_z, -INFINITY, 0);
    EXPECT_VALID(init_std_xy, 0.0f, 0);
    EXPECT_VALID(init_std_z, -1.0f, 0);
    EXPECT_VALID(nn_min_z, -5.0f, 1);
    EXPECT_VALID(nn_min_z, NAN, 0);
    EXPECT_VALID(sup_margin, 0.0f, 1);
    EXPECT_VALID(sup_margin, -0.1f, 0);
    EXPECT_VALID(sup_max_speed, 0.0f, 0);
    EXPECT_VALID(sup_max_speed, INFINITY, 0);
    EXPECT_VALID(sup_max_var, 0.0f, 0);
    EXPECT_VALID(sup_max_var, NAN, 0);
#undef EXPECT_VALID
}

/* Positions received over the radio expire 2 s after the last packet that carried them; the host's stay,
 * and a radio packet does not overwrite them; a new host anchor takes the oldest radio slot of a full table. */
static void test_radio_positions_expire(void)
{
    const float p[3] = {1.0f, 2.0f, 3.0f}, q[3] = {-1.0f, 0.5f, 2.0f};
    unsigned id;
    estimator_init(&est, &no_model);
    CHECK(estimator_set_radio_anchor(&est, 200, p, 1000000u) == EST_OK);
    CHECK(estimator_set_anchor(&est, 7, p) == EST_OK);
    CHECK(estimator_set_radio_anchor(&est, 7, q, 1000000u) == EST_OK && estimator_anchor(&est, 7, 0)[0] == 1.0f);
    CHECK(estimator_anchor(&est, 200, 2999999u) != NULL && estimator_anchor(&est, 200, 3000000u) == NULL);
    CHECK(estimator_anchor(&est, 7, 90000000u) != NULL);
    CHECK(estimator_set_radio_anchor(&est, 200, q, 2500000u) == EST_OK);       /* refreshed */
    CHECK(estimator_anchor(&est, 200, 4400000u) != NULL && estimator_anchor(&est, 200, 4400000u)[0] == -1.0f);
    for (id = 0; id < ESTIMATOR_MAX_ANCHORS - 2; id++) {
        CHECK(estimator_set_anchor(&est, (uint8_t)(100 + id), p) == EST_OK);
    }
    CHECK(estimator_set_anchor(&est, 99, q) == EST_OK);            /* took the radio slot of 200 */
    CHECK(estimator_anchor(&est, 200, 2500000u) == NULL && estimator_anchor(&est, 99, 0)[0] == -1.0f);
}

static void test_anchor_ids_and_unknown_anchors(void)
{
    estimator_t before;
    estimator_result_t r;
    const float p[3] = {1.0f, 2.0f, 3.0f};
    unsigned id;
    estimator_init(&est, &no_model);
    /* any uint8 id, keyed: the table holds ESTIMATOR_MAX_ANCHORS of them */
    for (id = 0; id < ESTIMATOR_MAX_ANCHORS - 1; id++) {
        CHECK(estimator_set_anchor(&est, (uint8_t)(240 + id), p) == EST_OK);
    }
    CHECK(estimator_set_anchor(&est, 15, p) == EST_OK && est.anchor_known == 0xFFFFu);
    CHECK(estimator_set_anchor(&est, 240, p) == EST_OK);           /* moved, same slot */
    CHECK(estimator_set_anchor(&est, 16, p) == EST_ERR_BAD_ANCHOR_ID);   /* full of host positions */
    CHECK(estimator_set_radio_anchor(&est, 16, p, 0) == EST_ERR_BAD_ANCHOR_ID);
    CHECK(estimator_anchor(&est, 254, 0) != NULL && estimator_anchor(&est, 255, 0) == NULL);
    estimator_init(&est, &no_model);
    CHECK(estimator_set_anchor(&est, 15, p) == EST_OK);
    memcpy(&before, &est, sizeof est);
    CHECK(estimator_on_twr(&est, 1000, 3, 2.0f, &r) == EST_ERR_UNKNOWN_ANCHOR);
    CHECK(estimator_on_twr(&est, 1000, 200, 2.0f, &r) == EST_ERR_UNKNOWN_ANCHOR);
    CHECK(estimator_on_tdoa(&est, 1000, 15, 4, 0.5f, &r) == EST_ERR_UNKNOWN_ANCHOR);
    CHECK(estimator_on_tdoa(&est, 1000, 4, 15, 0.5f, &r) == EST_ERR_UNKNOWN_ANCHOR);
    CHECK(memcmp(&before, &est, sizeof est) == 0);
    CHECK(estimator_on_twr(&est, 1000, 15, 2.0f, &r) == EST_OK);
}

static void test_time_backwards_refused_without_change(void)
{
    estimator_t before;
    estimator_result_t r;
    setup(EST_MODE_IMU, EST_STAGES_ALL, 0.0f, 0.0f, 1.0f);
    CHECK(estimator_on_imu(&est, 2000, still_acc, no_gyro) == EST_OK);
    CHECK(estimator_on_imu(&est, 2000, still_acc, no_gyro) == EST_OK); /* equal is fine */
    memcpy(&before, &est, sizeof est);
    CHECK(estimator_on_imu(&est, 1999, still_acc, no_gyro) == EST_ERR_TIME_BACKWARDS);
    CHECK(memcmp(&before, &est, sizeof est) == 0);
    CHECK(estimator_on_twr(&est, 5000, 0, 4.0f, &r) == EST_OK);
    CHECK(estimator_on_twr(&est, 5000, 1, 4.0f, &r) == EST_OK);
    memcpy(&before, &est, sizeof est);
    CHECK(estimator_on_twr(&est, 4999, 0, 4.0f, &r) == EST_ERR_TIME_BACKWARDS);
    CHECK(estimator_on_tdoa(&est, 4999, 0, 1, 0.1f, &r) == EST_ERR_TIME_BACKWARDS);
    CHECK(memcmp(&before, &est, sizeof est) == 0);
    /* IMU and UWB clocks are checked separately */
    CHECK(estimator_on_imu(&est, 3000, still_acc, no_gyro) == EST_OK);
    /* a reset forgets the time references (a new flight), keeps anchors */
    estimator_configure(&est, &est.cfg, 1);
    CHECK(estimator_on_imu(&est, 0, still_acc, no_gyro) == EST_OK);
    CHECK(estimator_on_twr(&est, 0, 0, 4.0f, &r) == EST_OK);
    /* without reset they are kept */
    CHECK(estimator_on_twr(&est, 10, 0, 4.0f, &r) == EST_OK);
    estimator_configure(&est, &est.cfg, 0);
    CHECK(estimator_on_twr(&est, 5, 0, 4.0f, &r) == EST_ERR_TIME_BACKWARDS);
}

static void test_static_twr_convergence(void)
{
    const float truth[3] = {1.0f, -0.5f, 1.2f};
    float pos[3], vel[3], quat[4], var[9];
    uint8_t mode;
    for (mode = 0; mode < 2; mode++) {
        /* gates off: the start is 1.6 m away, the kinematic gate would refuse every range */
        setup(mode, 0, 0.0f, 0.0f, 0.0f);
        run_static(truth, 10);
        estimator_state(&est, pos, vel, quat, var);
        CHECK_NEAR(pos[0], truth[0], 0.005);
        CHECK_NEAR(pos[1], truth[1], 0.005);
        CHECK_NEAR(pos[2], truth[2], 0.005);
        CHECK(fabsf(vel[0]) < 0.01f && fabsf(vel[1]) < 0.01f && fabsf(vel[2]) < 0.01f);
        CHECK(var[0] < 0.05f && var[1] < 0.05f && var[2] < 0.1f); /* from 1 m^2 */
        CHECK(est.divergences == 0);
        if (mode == EST_MODE_UWB_ONLY) {
            CHECK(est.imu_ignored == 10001);
            CHECK(quat[0] == 1.0f && quat[1] == 0.0f && quat[2] == 0.0f && quat[3] == 0.0f);
        } else {
            CHECK(est.predictions == 1000);
        }
    }
}

static void test_uwb_only_constant_velocity_tracking(void)
{
    const float v[3] = {0.5f, -0.3f, 0.1f}, p0[3] = {-1.0f, 1.0f, 1.0f};
    float pos[3], vel[3], quat[4], var[9];
    estimator_result_t r;
    int k, accepted = 0;
    setup(EST_MODE_UWB_ONLY, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    for (k = 0; k < 500; k++) { /* 5 s at 100 Hz, TDoA between consecutive anchors */
        const float t = 0.01f * (float)k;
        const float p[3] = {p0[0] + v[0] * t, p0[1] + v[1] * t, p0[2] + v[2] * t};
        const uint8_t a = (uint8_t)(k % 8), b = (uint8_t)((k + 1) % 8);
        CHECK(estimator_on_tdoa(&est, (uint64_t)k * 10000u, a, b, range_to(&est, b, p) - range_to(&est, a, p), &r) == EST_OK);
        accepted += r.status == EST_ACCEPTED;
        if (k > 300) {
            estimator_state(&est, pos, vel, quat, var);
            CHECK(fabsf(pos[0] - p[0]) < 0.005f && fabsf(pos[1] - p[1]) < 0.005f && fabsf(pos[2] - p[2]) < 0.005f);
        }
    }
    CHECK(accepted == 500);
    estimator_state(&est, pos, vel, quat, var);
    CHECK_NEAR(vel[0], v[0], 0.01);
    CHECK_NEAR(vel[1], v[1], 0.01);
    CHECK_NEAR(vel[2], v[2], 0.01);
    CHECK(est.predictions == 499); /* the first measurement only sets the state time */
}

/* Planar mode: HEIGHT pseudo-measurements pin z; bad values and time going backwards are refused. */
static void test_height_pseudo_measurement(void)
{
    estimator_result_t r;
    float pos[3], var[9];
    const float p0[3] = {0.5f, 0.5f, 1.0f};
    setup(EST_MODE_UWB_ONLY, 0, p0[0], p0[1], 0.0f);
    CHECK(estimator_on_height(&est, 1000, 1.0f, 0.0f) == EST_ERR_BAD_VALUE);
    CHECK(estimator_on_height(&est, 1000, 1.0f, -1.0f) == EST_ERR_BAD_VALUE);
    CHECK(estimator_on_height(&est, 1000, 1.0f, 1e30f) == EST_ERR_BAD_VALUE); /* std^2 would overflow */
    CHECK(est.heights == 0);
    CHECK(estimator_on_height(&est, 1000, 1.0f, 0.01f) == EST_OK);
    estimator_state(&est, pos, NULL, NULL, var);
    CHECK_NEAR(pos[2], 1.0, 1e-3);  /* prior std 1 m, measurement 1 cm */
    CHECK(var[2] < 2e-4f);
    CHECK(est.heights == 1);
    CHECK(estimator_on_height(&est, 999, 1.0f, 0.01f) == EST_ERR_TIME_BACKWARDS);
    CHECK(est.heights == 1);
    CHECK(estimator_on_twr(&est, 1000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK(r.flags == EST_FLAG_HEIGHT_FUSED);
    CHECK(estimator_on_twr(&est, 2000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(r.flags == 0);
}

static void test_costs(void)
{
    estimator_result_t r;
    uint64_t t;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    setup(EST_MODE_IMU, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    for (t = 0; t <= 30000; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
    }
    CHECK(estimator_on_twr(&est, 30000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK(r.cost_predict > 0 && r.cost_update > 0);
    CHECK(estimator_on_twr(&est, 30000, 1, range_to(&est, 1, p0), &r) == EST_OK);
    CHECK(r.cost_predict == 0); /* no prediction since the previous result */
    CHECK(estimator_prediction_count(&est) == 3);
}

int main(void)
{
    RUN(test_default_config);
    RUN(test_config_validation);
    RUN(test_anchor_ids_and_unknown_anchors);
    RUN(test_radio_positions_expire);
    RUN(test_time_backwards_refused_without_change);
    RUN(test_static_twr_convergence);
    RUN(test_uwb_only_constant_velocity_tracking);
    RUN(test_height_pseudo_measurement);
    RUN(test_costs);
    return UNIT_DONE();
}
