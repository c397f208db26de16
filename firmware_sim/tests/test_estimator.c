/* estimator: config defaults/validation, anchors, time rules, statuses and gates in the pipeline,
 * bias network wiring, static convergence, UWB-only tracking, divergence guard, costs. */
#include <float.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "estimator.h"
#include "robust_update.h"
#include "unit.h"

static const bias_model_t no_model = {NULL, NULL, 0};
static estimator_t est; /* large: keep off the stack */

/* 8 anchors at the corners of a 7 x 8 x 3 m box centred at the origin, z from 0 to 3. */
static void set_box_anchors(estimator_t *e)
{
    int i;
    for (i = 0; i < 8; i++) {
        const float p[3] = {(i & 1) ? 3.5f : -3.5f, (i & 2) ? 4.0f : -4.0f, (i & 4) ? 3.0f : 0.0f};
        CHECK(estimator_set_anchor(e, (uint8_t)i, p) == EST_OK);
    }
}

static float range_to(const estimator_t *e, uint8_t id, const float p[3])
{
    const float *a = e->anchors[id];
    return sqrtf((p[0] - a[0]) * (p[0] - a[0]) + (p[1] - a[1]) * (p[1] - a[1]) + (p[2] - a[2]) * (p[2] - a[2]));
}

static void setup(uint8_t mode, uint8_t stages, float x, float y, float z)
{
    estimator_config_t cfg;
    estimator_init(&est, &no_model);
    estimator_default_config(&cfg);
    cfg.mode = mode;
    cfg.stages = stages;
    cfg.init_x = x;
    cfg.init_y = y;
    cfg.init_z = z;
    estimator_configure(&est, &cfg, 1);
    set_box_anchors(&est);
}

static const float still_acc[3] = {0.0f, 0.0f, EKF_GRAVITY};
static const float no_gyro[3] = {0.0f, 0.0f, 0.0f};

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

/* Stationary tag, IMU at 1 kHz, TWR round robin at 100 Hz, noiseless. */
static void run_static(const float truth[3], int seconds)
{
    estimator_result_t r;
    uint64_t t;
    uint8_t k = 0;
    for (t = 0; t <= (uint64_t)seconds * 1000000u; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
        if (t % 10000 == 5000) {
            CHECK(estimator_on_twr(&est, t, k, range_to(&est, k, truth), &r) == EST_OK);
            k = (uint8_t)((k + 1) % 8);
        }
    }
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

static void test_statuses(void)
{
    estimator_result_t r;
    ekf_t before;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    const float on_tag[3] = {0.0f, 0.0f, 1.0f};
    float h;

    /* geometry: an anchor exactly at the estimate */
    setup(EST_MODE_IMU, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    CHECK(estimator_set_anchor(&est, 9, on_tag) == EST_OK);
    memcpy(&before, &est.ekf, sizeof before);
    CHECK(estimator_on_twr(&est, 1000, 9, 0.5f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_GEOMETRY);
    CHECK(r.innovation == 0.0f && r.innovation_var == 0.0f && r.gain[0] == 0.0f);
    CHECK_NEAR(r.d_max, 0.25, 1e-6); /* at rest, dt_min = 10 ms, a_max 5000 */
    CHECK(memcmp(&before, &est.ekf, sizeof before) == 0);
    CHECK(estimator_on_tdoa(&est, 1000, 9, 9, 0.0f, &r) == EST_OK && r.status == EST_REJECTED_GEOMETRY);
    CHECK(estimator_on_tdoa(&est, 1000, 0, 9, 0.0f, &r) == EST_OK && r.status == EST_REJECTED_GEOMETRY);

    /* kinematic: rejected when |y| > d_max = 0.25 m (at rest); 0.2 m passes */
    h = range_to(&est, 0, p0);
    CHECK(estimator_on_twr(&est, 2000, 0, h + 0.3f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_KINEMATIC);
    CHECK_NEAR(r.innovation, 0.3, 1e-5);
    CHECK(r.innovation_var > 0.0625f && r.gain[0] == 0.0f && r.gain[1] == 0.0f && r.gain[2] == 0.0f);
    CHECK(memcmp(&before, &est.ekf, sizeof before) == 0);
    CHECK(estimator_on_twr(&est, 2000, 0, h + 0.2f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED && r.gain[0] != 0.0f);
    /* TDoA: twice the bound */
    {
        const float d = range_to(&est, 1, est.last_good_pos) - range_to(&est, 0, est.last_good_pos);
        CHECK(estimator_on_tdoa(&est, 3000, 0, 1, d + 0.55f, &r) == EST_OK);
        CHECK(r.status == EST_REJECTED_KINEMATIC);
        CHECK_NEAR(r.innovation, 0.55, 1e-5);
        CHECK(estimator_on_tdoa(&est, 3000, 0, 1, d + 0.45f, &r) == EST_OK);
        CHECK_NEAR(r.innovation, 0.45, 1e-5);
        CHECK(r.status != EST_REJECTED_KINEMATIC);
    }

    /* chi-square only: big innovations pass the (disabled) kinematic gate but not y^2/S */
    setup(EST_MODE_IMU, EST_STAGE_CHI2_GATE, p0[0], p0[1], p0[2]);
    h = range_to(&est, 0, p0);
    CHECK(estimator_on_twr(&est, 1000, 0, h + 3.0f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_CHI2);
    CHECK(r.innovation * r.innovation / r.innovation_var > est.cfg.chi2_twr);
    CHECK_NEAR(r.d_max, 0.25, 1e-6); /* reported although the gate is off */
    CHECK(estimator_on_twr(&est, 1000, 0, h + 1.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    CHECK(r.innovation * r.innovation / r.innovation_var <= est.cfg.chi2_twr);

    /* no gates: anything finite is used */
    setup(EST_MODE_IMU, 0, p0[0], p0[1], p0[2]);
    CHECK(estimator_on_twr(&est, 1000, 0, h + 3.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
}

/* The chi-square gate cannot lock an anchor out: with a sustained 1 m offset on anchor 0 (the others
 * exact, round robin every 10 ms) its ranges are rejected until its links have been rejected for longer
 * than GATE_CHI2_REOPEN_US, then let through; an isolated outlier is rejected. */
static void test_chi2_lockout_guard(void)
{
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    uint64_t t = 10000;
    int k, rejected = 0, first_accept = -1;
    setup(EST_MODE_IMU, EST_STAGE_CHI2_GATE, p0[0], p0[1], p0[2]);
    for (k = 0; k < 80; k++, t += 10000) { /* converge on exact ranges */
        CHECK(estimator_on_twr(&est, t, (uint8_t)(k % 8), range_to(&est, (uint8_t)(k % 8), p0), &r) == EST_OK);
        CHECK(r.status == EST_ACCEPTED);
    }
    CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0) + 1.0f, &r) == EST_OK); /* isolated */
    CHECK(r.status == EST_REJECTED_CHI2);
    for (k = 1; k < 8; k++) {
        t += 10000;
        CHECK(estimator_on_twr(&est, t, (uint8_t)k, range_to(&est, (uint8_t)k, p0), &r) == EST_OK);
    }
    for (k = 0; k < 6; k++) { /* anchor 0 now every 80 ms, always 1 m long */
        int j;
        t += 10000;
        CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0) + 1.0f, &r) == EST_OK);
        if (r.status == EST_REJECTED_CHI2 && first_accept < 0) {
            rejected++;
        } else if (r.status == EST_ACCEPTED && first_accept < 0) {
            first_accept = k;
        }
        for (j = 1; j < 8; j++) {
            t += 10000;
            CHECK(estimator_on_twr(&est, t, (uint8_t)j, range_to(&est, (uint8_t)j, p0), &r) == EST_OK);
        }
    }
    /* its links rejected since the isolated outlier (its last fusion 80 ms before it): at its 3rd
     * measurement in the loop they had been for 0.24 s > 0.2 s */
    CHECK(rejected == 2 && first_accept == 2);
}

static void test_gate_dt_references(void)
{
    estimator_result_t r;
    uint64_t t;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    /* IMU mode: dt from the last prediction (20 ms) to the measurement (35 ms) = 15 ms */
    setup(EST_MODE_IMU, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    for (t = 0; t <= 25000; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
    }
    CHECK(est.predictions == 2 && est.ekf.t_us == 20000);
    CHECK(estimator_on_twr(&est, 35000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.5 * 5000.0 * 0.015 * 0.015, 1e-5);
    /* UWB-only: first measurement dt_min, then the time since the previous state time */
    setup(EST_MODE_UWB_ONLY, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    CHECK(estimator_on_twr(&est, 7000000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.25, 1e-6);
    CHECK(est.predictions == 0);
    CHECK(estimator_on_twr(&est, 7030000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.5 * 5000.0 * 0.03 * 0.03, 1e-4);
    CHECK(est.predictions == 1);
}

/* A network whose output depends only on the sum of its scaled inputs, so the test does not depend
 * on the weight storage order: all first-layer weights 1, second 0.02 (x 50 = 1), output 0.02. */
static float ones[BIAS_NN_MAX_IN * BIAS_NN_HIDDEN], w2[BIAS_NN_HIDDEN * BIAS_NN_HIDDEN], w3[BIAS_NN_HIDDEN];
static const float zeros[BIAS_NN_HIDDEN] = {0.0f};
static const float in_min[3] = {-10.0f, -10.0f, -10.0f}, in_max[3] = {10.0f, 10.0f, 10.0f};

static double expected_bias(const float dp[3])
{
    double s = 0.0, out;
    int i;
    for (i = 0; i < 3; i++) {
        s += (dp[i] + 10.0) / 20.0;
    }
    out = (s - 1.0) * 2.0 - 1.0; /* b3 = -1; out range [-1, 1] */
    return out < -1.0 ? -1.0 : (out > 1.0 ? 1.0 : out);
}

static void test_bias_network_wiring(void)
{
    bias_nn_t net;
    bias_model_t model;
    estimator_config_t cfg;
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    float dp[3], h;
    int i;
    for (i = 0; i < BIAS_NN_MAX_IN * BIAS_NN_HIDDEN; i++) {
        ones[i] = 1.0f;
    }
    for (i = 0; i < BIAS_NN_HIDDEN * BIAS_NN_HIDDEN; i++) {
        w2[i] = 0.02f;
    }
    for (i = 0; i < BIAS_NN_HIDDEN; i++) {
        w3[i] = 0.02f;
    }
    memset(&net, 0, sizeof net);
    net.layout = BIAS_LAYOUT_TWR_POS;
    net.n_in = 3;
    net.w1 = ones;
    net.b1 = zeros;
    net.w2 = w2;
    net.b2 = zeros;
    net.w3 = w3;
    net.b3 = -1.0f;
    net.in_min = in_min;
    net.in_max = in_max;
    net.out_min = -1.0f;
    net.out_max = 1.0f;
    model.twr = &net;
    model.tdoa = NULL;
    model.hash = 0;

    estimator_init(&est, &model);
    estimator_default_config(&cfg);
    cfg.init_x = p0[0];
    cfg.init_y = p0[1];
    cfg.init_z = p0[2];
    cfg.stages = EST_STAGE_BIAS_NN; /* no gates: the bias must not be hidden by a rejection */
    estimator_configure(&est, &cfg, 1);
    set_box_anchors(&est);
    for (i = 0; i < 3; i++) {
        dp[i] = est.anchors[7][i] - p0[i]; /* anchor - tag, from the estimate */
    }
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 1000, 7, h, &r) == EST_OK);
    CHECK(fabs(expected_bias(dp)) < 0.99);
    CHECK_NEAR(r.bias, expected_bias(dp), 1e-5);
    CHECK_NEAR(r.innovation, -r.bias, 1e-5); /* y = (z - bias) - h with z = h */

    /* std head: S = H P H^T + std^2 with the network's std instead of std_twr, bounded by its limits */
    {
        estimator_result_t r_head;
        const float s_plain = r.innovation_var;
        net.w3s = zeros;
        net.std_min = 0.02f;
        net.std_max = 0.5f;
        net.b3s = logf(0.1f);
        estimator_configure(&est, &cfg, 1); /* without the NN_STD stage: the configured std */
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_head) == EST_OK);
        CHECK_NEAR(r_head.innovation_var, s_plain, 1e-7);
        cfg.stages = EST_STAGE_BIAS_NN | EST_STAGE_NN_STD;
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_head) == EST_OK);
        CHECK_NEAR(r_head.bias, r.bias, 1e-6);
        CHECK_NEAR(r_head.innovation_var - s_plain, 0.1f * 0.1f - cfg.std_twr * cfg.std_twr, 1e-5);
        net.b3s = logf(5.0f); /* above std_max: clamped */
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_head) == EST_OK);
        CHECK_NEAR(r_head.innovation_var - s_plain, 0.25f - cfg.std_twr * cfg.std_twr, 1e-5);
        net.b3s = logf(1e-4f); /* below std_min: clamped */
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_head) == EST_OK);
        CHECK_NEAR(r_head.innovation_var - s_plain, 0.02f * 0.02f - cfg.std_twr * cfg.std_twr, 1e-5);
        /* below nn_min_z (0.5 m, the paper's take-off rule) the network does not run: the configured std again */
        cfg.init_z = 0.4f;
        cfg.nn_min_z = 0.5f;
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, 3.0f, &r_head) == EST_OK);
        CHECK(r_head.bias == 0.0f);
        {
            estimator_result_t r_nohead;
            net.w3s = NULL;
            estimator_configure(&est, &cfg, 1);
            CHECK(estimator_on_twr(&est, 1000, 7, 3.0f, &r_nohead) == EST_OK);
            CHECK_NEAR(r_head.innovation_var, r_nohead.innovation_var, 1e-7);
        }
        cfg.init_z = p0[2];
        cfg.nn_min_z = -1.0f;
        cfg.stages = EST_STAGE_BIAS_NN;
        estimator_configure(&est, &cfg, 1);
    }

    /* out of the training range: the correction fades to 0 over 10 % of the range width */
    {
        static const float narrow_min[3] = {-10.0f, -10.0f, -10.0f};
        float narrow_max[3];
        estimator_result_t r_out;
        const float in_bias = r.bias;
        CHECK(bias_nn_ood_excess(&net, dp) == 0.0f);
        for (i = 0; i < 3; i++) {
            narrow_max[i] = 10.0f;
        }
        /* dp[0] beyond in_max by 5 % of the range width: (dp - max) / (max - min) = 0.05, fade 0.5 */
        narrow_max[0] = (dp[0] + 0.05f * narrow_min[0]) / 1.05f;
        net.in_min = narrow_min;
        net.in_max = narrow_max;
        CHECK_NEAR(bias_nn_ood_excess(&net, dp), 0.05f, 1e-5);
        CHECK_NEAR(bias_nn_ood_fade(0.05f), 0.5f, 1e-6);
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_out) == EST_OK);
        CHECK_NEAR(r_out.bias, 0.5f * bias_nn_predict(&net, dp, NULL), 1e-6);
        narrow_max[0] = narrow_min[0] + 0.5f * (dp[0] - narrow_min[0]); /* excess 1: no correction */
        CHECK(bias_nn_ood_excess(&net, dp) > BIAS_NN_OOD_MARGIN);
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_out) == EST_OK);
        CHECK(r_out.bias == 0.0f);
        CHECK(bias_nn_ood_fade(NAN) == 0.0f && bias_nn_ood_fade(0.0f) == 1.0f && bias_nn_ood_fade(1.0f) == 0.0f);
        net.in_min = in_min;
        net.in_max = in_max;
        estimator_configure(&est, &cfg, 1);
        CHECK(estimator_on_twr(&est, 1000, 7, h, &r_out) == EST_OK);
        CHECK_NEAR(r_out.bias, in_bias, 1e-7);
    }

    /* at 0.4 m with the power-up nn_min_z (-1): corrected; with the floor at 0.5 m: no correction */
    cfg.init_z = 0.4f;
    estimator_configure(&est, &cfg, 1);
    CHECK(estimator_on_twr(&est, 1000, 7, 3.0f, &r) == EST_OK);
    {
        const float p_low[3] = {p0[0], p0[1], 0.4f};
        for (i = 0; i < 3; i++) {
            dp[i] = est.anchors[7][i] - p_low[i];
        }
        CHECK(r.bias != 0.0f);
        CHECK_NEAR(r.bias, expected_bias(dp), 1e-5);
    }
    cfg.nn_min_z = 0.5f;
    estimator_configure(&est, &cfg, 1);
    CHECK(estimator_on_twr(&est, 1000, 7, 3.0f, &r) == EST_OK);
    CHECK(r.bias == 0.0f);
    cfg.nn_min_z = -1.0f;
    /* stage off: no correction */
    cfg.init_z = p0[2];
    cfg.stages = 0;
    estimator_configure(&est, &cfg, 1);
    CHECK(estimator_on_twr(&est, 1000, 7, h, &r) == EST_OK);
    CHECK(r.bias == 0.0f && r.innovation == 0.0f);
    /* no network for TDoA */
    cfg.stages = EST_STAGE_BIAS_NN;
    estimator_configure(&est, &cfg, 1);
    CHECK(estimator_on_tdoa(&est, 1000, 6, 7, 0.1f, &r) == EST_OK);
    CHECK(r.bias == 0.0f);
    /* unknown layout: no correction */
    net.layout = 99;
    CHECK(estimator_on_twr(&est, 2000, 7, h, &r) == EST_OK);
    CHECK(r.bias == 0.0f);
}

static float dist3(const float a[3], const float b[3])
{
    const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return sqrtf(dx * dx + dy * dy + dz * dz);
}

static void test_robust_update(void)
{
    estimator_result_t r;
    float pos_plain[3], pos_robust[3], h;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    /* the weight: ~1 for a residual within the noise, R/w large for a gross one, bounded for NaN */
    CHECK_NEAR(robust_r_var(0.0f, 0.01f, 0.01f), 0.01f, 1e-9);
    CHECK(robust_r_var(0.05f, 0.01f, 0.01f) < 0.0102f);
    CHECK(robust_r_var(2.0f, 0.01f, 0.01f) > 10.0f * 0.01f);
    CHECK_NEAR(robust_r_var(NAN, 0.01f, 0.01f), 0.01f / ROBUST_W_MIN, 1e-3);
    CHECK(robust_r_var(-2.0f, 0.01f, 0.01f) == robust_r_var(2.0f, 0.01f, 0.01f));
    /* a converged filter (2 s of good ranges), then a 2 m outlier, no gates: the plain update follows it,
     * the robust one barely moves (with an uncertain prior it could not tell, and should not) */
    setup(EST_MODE_IMU, 0, p0[0], p0[1], p0[2]);
    run_static(p0, 2);
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 2001000u, 7, h + 2.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    estimator_state(&est, pos_plain, NULL, NULL, NULL);
    setup(EST_MODE_IMU, EST_STAGE_ROBUST_UPDATE, p0[0], p0[1], p0[2]);
    run_static(p0, 2);
    CHECK(estimator_on_twr(&est, 2001000u, 7, h + 2.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    estimator_state(&est, pos_robust, NULL, NULL, NULL);
    CHECK(dist3(pos_plain, p0) > 0.1f);
    CHECK(dist3(pos_robust, p0) < 0.2f * dist3(pos_plain, p0));
    CHECK(r.innovation_var > 10.0f * (0.25f * 0.25f)); /* S of the update carries the inflated R */
}

static void test_nn_monitor(void)
{
    static nn_monitor_t mon;
    unsigned k;
    memset(&mon, 0, sizeof mon);
    nn_monitor_reset(&mon);
    CHECK(nn_monitor_enabled(&mon, 3, 4) && !nn_monitor_enabled(&mon, 16, 4));
    /* a correction that doubles the innovation (y = 0.2 with it, 0.1 without): off after 64 */
    for (k = 0; k + 1 < NN_MON_MIN_SAMPLES; k++) {
        CHECK(nn_monitor_observe(&mon, 3, 4, 0.2f, -0.1f, 0.0225f) == 0);
    }
    CHECK(nn_monitor_enabled(&mon, 3, 4));
    CHECK(nn_monitor_observe(&mon, 3, 4, 0.2f, -0.1f, 0.0225f) == 1);
    CHECK(!nn_monitor_enabled(&mon, 3, 4) && mon.disabled == 1u);
    CHECK(nn_monitor_observe(&mon, 3, 4, 0.2f, -0.1f, 0.0225f) == 0 && mon.disabled == 1u); /* once */
    /* a correction that helps (y = 0.02 with it, 0.1 without) is never switched off */
    for (k = 0; k < 1000u; k++) {
        CHECK(nn_monitor_observe(&mon, 5, 6, 0.02f, 0.08f, 0.0225f) == 0);
    }
    CHECK(nn_monitor_enabled(&mon, 5, 6));
    /* one gross outlier does not decide: clipped at 9 S */
    for (k = 0; k < 200u; k++) {
        CHECK(nn_monitor_observe(&mon, 7, 7, (k == 100u) ? 50.0f : 0.02f, 0.08f, 0.0225f) == 0);
    }
    (void)nn_monitor_observe(&mon, 7, 7, NAN, 0.1f, 0.0225f); /* NaN: clipped like an outlier */
    CHECK(nn_monitor_enabled(&mon, 7, 7));
    nn_monitor_reset(&mon);
    CHECK(nn_monitor_enabled(&mon, 3, 4) && mon.disabled == 1u); /* new flight: trusted again, count kept */
}

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
 * the reason in the next result's flags. */
static void test_supervisor_bounds(void)
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
    RUN(test_statuses);
    RUN(test_gate_dt_references);
    RUN(test_chi2_lockout_guard);
    RUN(test_bias_network_wiring);
    RUN(test_robust_update);
    RUN(test_nn_monitor);
    RUN(test_divergence_guard);
    RUN(test_supervisor_bounds);
    RUN(test_height_pseudo_measurement);
    RUN(test_costs);
    return UNIT_DONE();
}
