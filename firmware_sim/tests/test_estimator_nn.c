/* estimator: the bias network's wiring (correction, std head, out-of-range fade, height floor, stages)
 * and the network monitor. */
#include <string.h>

#include "estimator_fixture.h"

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

static bias_nn_t net;       /* the network above, the TWR network of `model` */
static bias_model_t model;

/* `net` and `model` set up, the estimator configured at p0 with only the bias stage (no gates: the bias must
 * not be hidden by a rejection), in the box of anchors. */
static void setup_network(estimator_config_t *cfg, const float p0[3])
{
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
    estimator_default_config(cfg);
    cfg->init_x = p0[0];
    cfg->init_y = p0[1];
    cfg->init_z = p0[2];
    cfg->stages = EST_STAGE_BIAS_NN;
    estimator_configure(&est, cfg, 1);
    set_box_anchors(&est);
}

/* anchor 7 - tag, the network's input */
static void offset_to_anchor7(const float p[3], float dp[3])
{
    int i;
    for (i = 0; i < 3; i++) {
        dp[i] = est.anchors[7][i] - p[i];
    }
}

static void test_bias_network_wiring(void)
{
    estimator_config_t cfg;
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    float dp[3], h;
    setup_network(&cfg, p0);
    offset_to_anchor7(p0, dp); /* from the estimate */
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 1000, 7, h, &r) == EST_OK);
    CHECK(fabs(expected_bias(dp)) < 0.99);
    CHECK_NEAR(r.bias, expected_bias(dp), 1e-5);
    CHECK_NEAR(r.innovation, -r.bias, 1e-5); /* y = (z - bias) - h with z = h */
}

/* std head: S = H P H^T + std^2 with the network's std instead of std_twr, bounded by its limits */
static void test_bias_network_std_head(void)
{
    estimator_config_t cfg;
    estimator_result_t r, r_head;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    float h, s_plain;
    setup_network(&cfg, p0);
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 1000, 7, h, &r) == EST_OK);
    s_plain = r.innovation_var;
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
}

/* out of the training range: the correction fades to 0 over 10 % of the range width */
static void test_bias_network_out_of_range_fade(void)
{
    estimator_config_t cfg;
    estimator_result_t r, r_out;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    static const float narrow_min[3] = {-10.0f, -10.0f, -10.0f};
    float narrow_max[3], dp[3], h, in_bias;
    int i;
    setup_network(&cfg, p0);
    offset_to_anchor7(p0, dp);
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 1000, 7, h, &r) == EST_OK);
    in_bias = r.bias;
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

/* The height floor (nn_min_z), the stage switch, TDoA without a network and an unknown layout. */
static void test_bias_network_floor_and_stages(void)
{
    estimator_config_t cfg;
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    float dp[3], h;
    setup_network(&cfg, p0);
    h = range_to(&est, 7, p0);
    /* at 0.4 m with the power-up nn_min_z (-1): corrected; with the floor at 0.5 m: no correction */
    cfg.init_z = 0.4f;
    estimator_configure(&est, &cfg, 1);
    CHECK(estimator_on_twr(&est, 1000, 7, 3.0f, &r) == EST_OK);
    {
        const float p_low[3] = {p0[0], p0[1], 0.4f};
        offset_to_anchor7(p_low, dp);
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

int main(void)
{
    RUN(test_bias_network_wiring);
    RUN(test_bias_network_std_head);
    RUN(test_bias_network_out_of_range_fade);
    RUN(test_bias_network_floor_and_stages);
    RUN(test_nn_monitor);
    return UNIT_DONE();
}
