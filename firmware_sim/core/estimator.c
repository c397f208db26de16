/* The per-measurement pipeline (ARCHITECTURE.md "Per UWB measurement pipeline"). */
#include "estimator.h"

#include <math.h>
#include <string.h>

#include "gate_chi2.h"
#include "gate_kinematic.h"
#include "mm_kinds.h"
#include "platform.h"
#include "robust_update.h"
#include "supervisor.h"
#include "time_ms.h"

/* The gate and the pair monitor hold per-anchor state for every anchor the estimator holds. */
typedef char est_check_anchors[(GATE_KIN_ANCHORS == ESTIMATOR_MAX_ANCHORS && NN_MON_ANCHORS == ESTIMATOR_MAX_ANCHORS &&
                                BIAS_ST_ANCHORS == ESTIMATOR_MAX_ANCHORS)
                               ? 1 : -1];

/* Filter at the configured init position; time references forgotten. */
static void reset_filter(estimator_t *est)
{
    const float pos[3] = {est->cfg.init_x, est->cfg.init_y, est->cfg.init_z};
    nn_monitor_reset(&est->nnmon); /* a new flight: every pair trusted again */
    bias_states_reset(&est->bstates);
    takeoff_reset(&est->takeoff);
    ekf_init(&est->ekf, pos, est->cfg.init_std_xy, est->cfg.init_std_z);
    memcpy(est->last_good_pos, pos, sizeof pos);
    est->has_imu_time = 0;
    est->has_uwb_time = 0;
    est->has_height_time = 0;
    est->t_height_us = 0;
    est->t_imu_us = 0;
    est->t_uwb_us = 0;
    gate_kinematic_reset(&est->kin);
    est->cost_predict = 0;
    est->flags = 0;
}

void estimator_init(estimator_t *est, const bias_model_t *model)
{
    memset(est, 0, sizeof *est);
    estimator_default_config(&est->cfg);
    est->model = model;
    reset_filter(est);
}

void estimator_configure(estimator_t *est, const estimator_config_t *cfg, int reset)
{
    est->cfg = *cfg;
    if (reset) {
        reset_filter(est);
    }
}

/* Bias (measured - true) from the network of this kind, or 0 when the stage is off, there is no
 * network, or the estimate is below nn_min_z (power-up -1: every height; 0.5 m is the paper's take-off rule,
 * the out-of-range fade below guards heights the network never saw).
 * Outside the network's training range the correction fades to 0 (bias_nn_ood_fade) and *std_out, the
 * predicted std, moves to cfg_std by the same factor. *std_out is 0 when the network has no std head, did
 * not run or the stage NN_STD is off: the caller then uses the configured std. */
static float nn_bias(const estimator_t *est, const bias_nn_t *net, const float *anchor_a,
                     const float *anchor_b, float cfg_std, float *std_out)
{
    float rpy[3], feat[BIAS_NN_MAX_IN], fade, bias;
    *std_out = 0.0f;
    if (!(est->cfg.stages & EST_STAGE_BIAS_NN) || net == NULL || !(est->ekf.x[EKF_Z] > est->cfg.nn_min_z)) {
        return 0.0f;
    }
    ekf_quat_to_rpy(est->ekf.q, rpy);
    if (bias_nn_features(net->layout, &est->ekf.x[EKF_X], rpy, anchor_a, anchor_b, feat) == 0) {
        return 0.0f;
    }
    fade = bias_nn_ood_fade(bias_nn_ood_excess(net, feat));
    if (fade <= 0.0f) {
        return 0.0f; /* far outside: not even evaluated */
    }
    /* The std head (its expf) only when NN_STD will use it. */
    bias = bias_nn_predict(net, feat, (est->cfg.stages & EST_STAGE_NN_STD) ? std_out : NULL);
    if (*std_out > 0.0f) {
        *std_out = fade * *std_out + (1.0f - fade) * cfg_std;
    }
    return fade * bias;
}

/* UWB-only: constant-velocity prediction to t_us (the first measurement only sets the state time, so
 * a late first measurement does not inflate P). IMU mode: nothing (updates apply at the last
 * prediction). */
static void predict_cv_to(estimator_t *est, uint64_t t_us)
{
    ekf_t *ekf = &est->ekf;
    uint32_t c0;
    if (est->cfg.mode != EST_MODE_UWB_ONLY) {
        return;
    }
    if (!ekf->has_time) {
        ekf->t_us = t_us;
        ekf->has_time = 1;
    } else if (t_us > ekf->t_us) {
        c0 = platform_cost_now();
        ekf_predict_cv(ekf, est->cfg.proc_cv_acc, uwb_u64_to_float(t_us - ekf->t_us) * 1e-6f);
        ekf->t_us = t_us;
        est->predictions++;
        estimator_supervise(est);
        est->cost_predict += platform_cost_now() - c0;
    }
}

/* The network's bias correction of a measurement (0 without a network, stage or pair), and in `std` the
 * standard deviation to fuse it with: the configured one (or the kind's own of the measurement), or with
 * NN_STD the network's own std of what it leaves when it predicts one. */
static float corrected_bias(estimator_t *est, const mm_kind_t *kind, const uint8_t ids[2],
                            const float *const anchors[2], const mm_input_t *in, float *std)
{
    const estimator_config_t *cfg = &est->cfg;
    const bias_nn_t *net = NULL;
    float bias, std_nn;
    if (est->model != NULL && kind->net != MM_NO_NET) {
        memcpy(&net, (const char *)est->model + kind->net, sizeof net);
    }
    *std = kind->std_of != NULL ? kind->std_of(in) : mm_cfg(cfg, kind->std_off);
    if (net != NULL && (cfg->stages & EST_STAGE_NN_MONITOR) && !nn_monitor_enabled(&est->nnmon, ids[0], ids[1])) {
        net = NULL; /* the monitor switched this pair's correction off */
    }
    bias = nn_bias(est, net, anchors[0], anchors[1], *std, &std_nn);
    if ((cfg->stages & EST_STAGE_NN_STD) && std_nn > 0.0f) {
        *std = std_nn;
    }
    return bias;
}

/* The gates' verdict on innovation y (variance S): kinematic first, then chi-square, which lets a link
 * through whose anchors have been rejected for longer than GATE_CHI2_REOPEN_US (rejected_us). On the floor
 * the chi-square test applies whatever the stages (the floor rule, not an outlier stage: begin_measurement). */
static uint8_t gate_status(const estimator_config_t *cfg, const mm_kind_t *kind, float y, float d_max, float S,
                           int64_t rejected_us, int on_floor)
{
    if ((cfg->stages & EST_STAGE_KINEMATIC_GATE) && !gate_kinematic_pass(y, d_max, kind->gate_factor)) {
        return EST_REJECTED_KINEMATIC;
    }
    if (((cfg->stages & EST_STAGE_CHI2_GATE) || on_floor) && !gate_chi2_pass(y, S, mm_cfg(cfg, kind->chi2_off)) &&
        !gate_chi2_reopened(rejected_us)) {
        return EST_REJECTED_CHI2;
    }
    return EST_ACCEPTED;
}

/* Fuse an accepted measurement; the robust stage inflates R by its M-estimation weight first (the gates
 * saw the nominal S); the bias states learn from the innovation. */
static void fuse(estimator_t *est, ekf_scalar_t *m, const float H[3], float y, uint64_t t_us, const uint8_t ids[2],
                 estimator_result_t *out)
{
    ekf_t *ekf = &est->ekf;
    if (est->cfg.stages & EST_STAGE_ROBUST_UPDATE) {
        const float r_w = robust_r_var(y, m->S - m->r_var, m->r_var);
        if (r_w > m->r_var) {
            ekf_scalar_prepare(ekf, m, H, y, r_w);
        }
    }
    ekf_scalar_apply(ekf, m);
    ekf_finalize(ekf);
    if ((est->cfg.stages & EST_STAGE_BIAS_STATES) && ids[0] < BIAS_ST_ANCHORS) {
        bias_states_update(&est->bstates, ids[0], ids[1], y, m->S);
    }
    gate_kinematic_fused(&est->kin, t_us, ids[0], ids[1]);
    estimator_supervise(est);
    out->gain[0] = m->K[EKF_X];
    out->gain[1] = m->K[EKF_Y];
    out->gain[2] = m->K[EKF_Z];
}

/* The start of every measurement: the CV prediction, the time rule's reference, and d_max, reported
 * whatever happens next (plots). The velocity norm is frame independent and the CV prediction does not
 * change the velocity. On the floor (the IMU says so: before take-off, after a touchdown; or a range to the
 * floor) the links to low anchors read metres long for seconds: the gates do not re-open there (no widening,
 * no lock-out guard), the chi-square test applies in every configuration, and the CV model (UWB-only), which
 * cannot see the vehicle stop, holds it at rest. Returns 1 on the floor. */
static int begin_measurement(estimator_t *est, const mm_kind_t *kind, uint64_t t_us, const uint8_t ids[2],
                             float z, estimator_result_t *out)
{
    const estimator_config_t *cfg = &est->cfg;
    const uint64_t t_ref = est->ekf.t_us;
    const int have_ref = est->ekf.has_time;
    float dt;
    int on_floor;
    /* every field zeroed, field by field (GCC turns a struct clear into a memset call: ~120 instructions) */
    out->status = 0;
    out->flags = 0;
    out->innovation = out->innovation_var = out->bias = out->d_max = 0.0f;
    out->gain[0] = out->gain[1] = out->gain[2] = 0.0f;
    out->cost_nn = out->cost_gates = out->cost_update = out->cost_predict = 0;
    predict_cv_to(est, t_us); /* its supervisor check still sees the previous measurement's time (gap) */
    est->t_uwb_us = t_us;
    est->has_uwb_time = 1;
    out->cost_predict = est->cost_predict;
    est->cost_predict = 0;
    if (kind->floor_below > 0.0f) {
        takeoff_on_floor_range(&est->takeoff, t_us, z < kind->floor_below);
    }
    on_floor = takeoff_on_floor(&est->takeoff, estimator_floor_from_imu(cfg), t_us);
    if (on_floor && cfg->mode == EST_MODE_UWB_ONLY) {
        ekf_hold_at_rest(&est->ekf);
    }
    dt = gate_kinematic_window(&est->kin, t_us, ids[0], ids[1], t_ref, have_ref, cfg->gate_dt_min, !on_floor);
    out->d_max = gate_kinematic_dmax(&est->ekf.x[EKF_PX], dt, mm_cfg(cfg, kind->a_max_off));
    return on_floor;
}

/* The pipeline for one measurement z of a kind; ids and anchors: the kind's anchors' slots and positions
 * (a one-anchor kind repeats A). */
static void process(estimator_t *est, const mm_kind_t *kind, uint64_t t_us, const uint8_t ids[2],
                    const float *const anchors[2], float z, estimator_result_t *out)
{
    ekf_t *ekf = &est->ekf;
    const estimator_config_t *cfg = &est->cfg;
    const mm_input_t in = {&ekf->x[EKF_X], (const float(*)[3])ekf->R, anchors[0],
                           kind->n_anchors > 1 ? anchors[1] : NULL, z, cfg};
    float h, H[3], y, bias, std, b_st = 0.0f, var_st = 0.0f;
    ekf_scalar_t m;
    uint32_t c0, c1, c2, c3;
    int rc;
    const int on_floor = begin_measurement(est, kind, t_us, ids, z, out);

    /* 1. measurement model */
    c0 = platform_cost_now();
    rc = kind->model(&in, &h, H);
    c1 = platform_cost_now();
    if (rc != MM_OK) {
        out->status = rc == MM_OUT_OF_BASELINE ? EST_REJECTED_BASELINE : EST_REJECTED_GEOMETRY;
        est->baseline_rejects += rc == MM_OUT_OF_BASELINE;
        out->cost_update = c1 - c0;
        out->flags = est->flags;
        est->flags = 0;
        return;
    }
    /* 2. bias: the network's, and with BIAS_STATES the slowly varying rest, from the innovations of
     * earlier measurements */
    bias = corrected_bias(est, kind, ids, anchors, &in, &std);
    if ((cfg->stages & EST_STAGE_BIAS_STATES) && kind->n_anchors > 0) {
        bias_states_predict(&est->bstates, t_us, ids[0], ids[1], &b_st, &var_st);
    }
    y = (z - bias - b_st) - h;
    c2 = platform_cost_now();
    /* 3./4. gates (S is needed by the chi-square gate and reported in every case) */
    ekf_scalar_prepare(ekf, &m, H, y, std * std + var_st);
    out->status = gate_status(cfg, kind, y, out->d_max, m.S, est->kin.rejected_us, on_floor);
    /* the monitor compares what the filter sees with and without the correction, whatever the gates said */
    if ((cfg->stages & EST_STAGE_NN_MONITOR) && bias != 0.0f &&
        nn_monitor_observe(&est->nnmon, ids[0], ids[1], y, bias, m.S)) {
        est->flags = (uint8_t)(est->flags | EST_FLAG_NN_PAIR_OFF);
    }
    c3 = platform_cost_now();
    /* 5. update */
    if (out->status == EST_ACCEPTED) {
        fuse(est, &m, H, y, t_us, ids, out);
    }
    out->innovation = y;
    out->innovation_var = m.S;
    out->bias = bias + b_st;
    out->cost_nn = c2 - c1;
    out->cost_gates = c3 - c2;
    out->cost_update = (c1 - c0) + (platform_cost_now() - c3);
    out->flags = est->flags;
    est->flags = 0;
}

/* The per-anchor state (gate, pair monitor, bias states) is kept by slot: the slot index goes down the
 * pipeline in place of the id. A kind that names no anchor (a sensor) is its own link: slot
 * GATE_KIN_SENSOR, no anchor position, no bias states. */
int estimator_on_meas(estimator_t *est, uint8_t kind, uint64_t t_us, const uint8_t anchor_ids[2], float z,
                      estimator_result_t *out)
{
    const mm_kind_t *row = mm_kind(kind);
    uint8_t slots[2] = {GATE_KIN_SENSOR, GATE_KIN_SENSOR};
    const float *anchors[2] = {NULL, NULL};
    int k;
    if (row == NULL) {
        return EST_ERR_UNKNOWN_KIND;
    }
    for (k = 0; k < 2 && row->n_anchors > 0; k++) {
        const int s = estimator_anchor_slot(est, anchor_ids[k < row->n_anchors ? k : 0], t_us);
        if (s < 0) {
            return EST_ERR_UNKNOWN_ANCHOR;
        }
        slots[k] = (uint8_t)s;
        anchors[k] = est->anchors[s];
    }
    if (est->has_uwb_time && t_us < est->t_uwb_us) {
        return EST_ERR_TIME_BACKWARDS;
    }
    process(est, row, t_us, slots, anchors, z, out);
    return EST_OK;
}

int estimator_on_twr(estimator_t *est, uint64_t t_us, uint8_t anchor, float range,
                     estimator_result_t *out)
{
    const uint8_t ids[2] = {anchor, anchor};
    return estimator_on_meas(est, MM_KIND_TWR, t_us, ids, range, out);
}

int estimator_on_tdoa(estimator_t *est, uint64_t t_us, uint8_t anchor_a, uint8_t anchor_b, float diff,
                      estimator_result_t *out)
{
    const uint8_t ids[2] = {anchor_a, anchor_b};
    return estimator_on_meas(est, MM_KIND_TDOA, t_us, ids, diff, out);
}

/* Beyond this std [m] a height carries no information, and its square (R) could overflow. */
#define EST_MAX_HEIGHT_STD 1000.0f

int estimator_on_height(estimator_t *est, uint64_t t_us, float z, float std)
{
    static const float h[3] = {0.0f, 0.0f, 1.0f};
    ekf_t *ekf = &est->ekf;
    ekf_scalar_t m;
    if (!(std > 0.0f && std <= EST_MAX_HEIGHT_STD)) {
        return EST_ERR_BAD_VALUE;
    }
    if (est->has_height_time && t_us < est->t_height_us) {
        return EST_ERR_TIME_BACKWARDS;
    }
    est->t_height_us = t_us;
    est->has_height_time = 1;
    predict_cv_to(est, t_us);
    ekf_scalar_update(ekf, &m, h, z - ekf->x[EKF_Z], std * std);
    ekf_finalize(ekf);
    est->heights++;
    est->flags = (uint8_t)(est->flags | EST_FLAG_HEIGHT_FUSED);
    estimator_supervise(est);
    return EST_OK;
}

void estimator_state(const estimator_t *est, float pos[3], float vel_world[3], float quat[4],
                     float var[9])
{
    ekf_state_t s;
    ekf_externalize(&est->ekf, &s);
    if (pos != NULL) {
        memcpy(pos, s.pos, sizeof s.pos);
    }
    if (vel_world != NULL) {
        memcpy(vel_world, s.vel_world, sizeof s.vel_world);
    }
    if (quat != NULL) {
        memcpy(quat, s.quat, sizeof s.quat);
    }
    if (var != NULL) {
        memcpy(var, s.var, sizeof s.var);
    }
}

uint32_t estimator_prediction_count(const estimator_t *est)
{
    return est->predictions;
}
