#include <string.h>

#include "bias_nn.h"
#include "frame_tx.h"
#include "config_msg.h" /* CONFIG message -> estimator_config_t (generated) */
#include "firmware.h"
#include "fw_internal.h"
#include "platform.h"
#include "proto_checks.h"
#include "uwb_meas.h"

#ifndef UWB_BUILD_ID
#define UWB_BUILD_ID "dev"
#endif

void fw_send_msg(firmware_t *fw, uwb_msg_t *msg)
{
    uint8_t enc[UWB_MAX_ENCODED + 1];
    msg->seq = fw->tx_seq++;
    fw->write(fw->write_ctx, enc, uwb_frame_encode(msg, enc));
}

void fw_send_error(firmware_t *fw, uint8_t code, const uwb_msg_t *bad, uint32_t detail)
{
    uwb_msg_t msg;
    memset(&msg, 0, sizeof msg);
    msg.type = UWB_MSG_ERROR;
    msg.u.error.code = code;
    msg.u.error.msg_type = bad->type;
    msg.u.error.msg_seq = bad->seq;
    msg.u.error.detail = detail;
    fw_send_msg(fw, &msg);
}

static void copy_str(uint8_t *dst, size_t cap, const char *src)
{
    size_t i;
    for (i = 0; i < cap; i++) {
        dst[i] = (uint8_t)(src[i] != '\0' ? src[i] : '\0');
        if (src[i] == '\0') {
            for (; i < cap; i++) {
                dst[i] = 0;
            }
            break;
        }
    }
}

void firmware_init(firmware_t *fw, fw_write_fn write, void *write_ctx, const char *target)
{
    memset(fw, 0, sizeof *fw);
    estimator_init(&fw->est, &bias_model_compiled);
    tdoa_engine_init(&fw->tdoa);
    {
        ctl_params_t cp;
        controller_default_params(&cp);
        controller_init(&fw->ctl, &cp);
    }
    frame_rx_init(&fw->rx);
    fw->write = write;
    fw->write_ctx = write_ctx;
    copy_str((uint8_t *)fw->target, sizeof fw->target, target);
}

static void on_hello(firmware_t *fw, const uwb_msg_t *in)
{
    uwb_msg_t msg;
    const bias_model_t *model = &bias_model_compiled;
    memset(&msg, 0, sizeof msg);
    msg.type = UWB_MSG_HELLO_REPLY;
    msg.u.hello_reply.nonce = in->u.hello.nonce;
    msg.u.hello_reply.proto_version = UWB_PROTO_VERSION;
    msg.u.hello_reply.fw_major = FW_VERSION_MAJOR;
    msg.u.hello_reply.fw_minor = FW_VERSION_MINOR;
    msg.u.hello_reply.fw_patch = FW_VERSION_PATCH;
    msg.u.hello_reply.cost_unit = platform_cost_unit();
    msg.u.hello_reply.layout_twr = model->twr ? model->twr->layout : UWB_LAYOUT_NONE;
    msg.u.hello_reply.layout_tdoa = model->tdoa ? model->tdoa->layout : UWB_LAYOUT_NONE;
    msg.u.hello_reply.model_hash = model->hash;
    copy_str(msg.u.hello_reply.build_id, sizeof msg.u.hello_reply.build_id, UWB_BUILD_ID);
    memcpy(msg.u.hello_reply.target, fw->target, sizeof msg.u.hello_reply.target);
    fw_send_msg(fw, &msg);
}

static void on_stats_req(firmware_t *fw)
{
    uwb_msg_t msg;
    const fw_stats_t *s = &fw->stats;
    memset(&msg, 0, sizeof msg);
    msg.type = UWB_MSG_STATS;
    msg.u.stats.frames_ok = s->frames_ok;
    msg.u.stats.crc_errors = s->crc_errors;
    msg.u.stats.framing_errors = s->framing_errors;
    msg.u.stats.unknown_types = s->unknown_types;
    msg.u.stats.bad_lengths = s->bad_lengths;
    msg.u.stats.non_finite = s->non_finite;
    msg.u.stats.unknown_anchors = s->unknown_anchors;
    msg.u.stats.time_backwards = s->time_backwards;
    msg.u.stats.bad_configs = s->bad_configs;
    msg.u.stats.dropped_meas = s->dropped_meas;
    msg.u.stats.imu_samples = s->imu_samples;
    msg.u.stats.twr_meas = s->meas[MM_KIND_TWR];
    msg.u.stats.tdoa_meas = s->meas[MM_KIND_TDOA];
    msg.u.stats.results = s->results;
    msg.u.stats.predictions = estimator_prediction_count(&fw->est);
    msg.u.stats.seq_gaps = s->seq_gaps;
    msg.u.stats.radio_packets = s->radio_packets;
    msg.u.stats.radio_meas = s->radio_meas;
    msg.u.stats.radio_no_reference = s->radio_no_reference;
    msg.u.stats.radio_clock = s->radio_clock;
    msg.u.stats.radio_expired = s->radio_expired;
    msg.u.stats.radio_malformed = s->radio_malformed;
    msg.u.stats.radio_unknown_type = s->radio_unknown_type;
    msg.u.stats.radio_no_position = s->radio_no_position;
    msg.u.stats.divergences = fw->est.divergences;
    msg.u.stats.nn_pairs_disabled = fw->est.nnmon.disabled;
    msg.u.stats.baseline_rejects = fw->est.baseline_rejects;
    msg.u.stats.heights = fw->est.heights;
    msg.u.stats.bad_values = s->bad_values;
    fw_send_msg(fw, &msg);
}

static void on_config(firmware_t *fw, const uwb_msg_t *in)
{
    const uwb_config_t *c = &in->u.config;
    estimator_config_t cfg;
    config_from_msg(c, &cfg);
    /* Refuse the whole message: a half-applied configuration would be worse than none. */
    if (!config_msg_control_valid(c) || !estimator_config_valid(&cfg)) {
        fw->stats.bad_configs++;
        fw_send_error(fw, UWB_ERROR_CODE_BAD_CONFIG, in, 0);
        return;
    }
    estimator_configure(&fw->est, &cfg, c->reset);
    if (c->reset) {
        /* A new flight may restart its clock: the controller forgets its time and integrals too, the
         * TDoA engine its anchors (their stored times belong to the old clock). */
        controller_init(&fw->ctl, &fw->ctl.p);
        tdoa_engine_init(&fw->tdoa);
    }
}

static void fill_result(firmware_t *fw, uwb_result_t *r, const estimator_result_t *er)
{
    float pos[3], vel[3], quat[4], var[9];
    estimator_state(&fw->est, pos, vel, quat, var);
    r->status = er->status;
    r->innovation = er->innovation;
    r->innovation_var = er->innovation_var;
    r->bias = er->bias;
    r->d_max = er->d_max;
    r->gain_x = er->gain[0];
    r->gain_y = er->gain[1];
    r->gain_z = er->gain[2];
    r->cost_nn = er->cost_nn;
    r->cost_gates = er->cost_gates;
    r->cost_update = er->cost_update;
    r->cost_predict = er->cost_predict;
    r->px = pos[0];
    r->py = pos[1];
    r->pz = pos[2];
    r->vx = vel[0];
    r->vy = vel[1];
    r->vz = vel[2];
    r->qw = quat[0];
    r->qx = quat[1];
    r->qy = quat[2];
    r->qz = quat[3];
    r->var_x = var[0];
    r->var_y = var[1];
    r->var_z = var[2];
    r->var_vx = var[3];
    r->var_vy = var[4];
    r->var_vz = var[5];
    r->var_d0 = var[6];
    r->var_d1 = var[7];
    r->var_d2 = var[8];
    r->flags = er->flags;
}

void fw_send_result(firmware_t *fw, const uwb_msg_t *in, uint8_t kind, uint64_t t_us, const estimator_result_t *er,
                    uint32_t compute)
{
    uwb_msg_t out;
    memset(&out, 0, sizeof out);
    out.type = UWB_MSG_RESULT;
    out.u.result.meas_seq = in->seq;
    out.u.result.kind = kind;
    out.u.result.t_us = t_us;
    fill_result(fw, &out.u.result, er);
    out.u.result.compute = compute;
    fw->stats.results++;
    fw_send_msg(fw, &out);
}

void fw_refuse_measurement(firmware_t *fw, const uwb_msg_t *in, int rc, uint32_t detail)
{
    fw->stats.dropped_meas++;
    if (rc == EST_ERR_UNKNOWN_ANCHOR) {
        fw->stats.unknown_anchors++;
    } else if (rc == EST_ERR_TIME_BACKWARDS) {
        fw->stats.time_backwards++;
    }
    fw_send_error(fw, (uint8_t)rc, in, detail);
}

/* A measurement frame of any kind (uwb_meas.h, generated): through the estimator, answered by RESULT. */
static void on_measurement(firmware_t *fw, const uwb_msg_t *in, const uwb_meas_t *meas)
{
    estimator_result_t er;
    uint32_t t0, t1;
    int rc;
    memset(&er, 0, sizeof er);
    t0 = platform_cost_now();
    fw->stats.meas[meas->kind < MM_KIND_END ? meas->kind : 0]++;
    rc = estimator_on_meas(&fw->est, meas->kind, meas->t_us, meas->anchor, meas->value, &er);
    t1 = platform_cost_now();
    if (rc != EST_OK) {
        fw_refuse_measurement(fw, in, rc, (uint32_t)meas->anchor[0] | ((uint32_t)meas->anchor[1] << 8));
        return;
    }
    fw_send_result(fw, in, meas->kind, meas->t_us, &er, t1 - t0);
}

static void track_seq(firmware_t *fw, uint16_t seq)
{
    if (fw->rx_seq_valid && seq != fw->next_rx_seq) {
        uint16_t gap = (uint16_t)(seq - fw->next_rx_seq);
        /* A small forward jump means frames were lost; anything else is a host restart. */
        if (gap < 0x8000u) {
            fw->stats.seq_gaps += gap;
        }
    }
    fw->next_rx_seq = (uint16_t)(seq + 1u);
    fw->rx_seq_valid = 1;
}

static void on_anchor(firmware_t *fw, const uwb_msg_t *in)
{
    const float pos[3] = {in->u.anchor.x, in->u.anchor.y, in->u.anchor.z};
    const int rc = estimator_set_anchor(&fw->est, in->u.anchor.anchor_id, pos);
    if (rc != EST_OK) {
        /* STATS accounts for every frame not used: an anchor the device cannot hold is unknown. */
        fw->stats.unknown_anchors++;
        fw_send_error(fw, (uint8_t)rc, in, in->u.anchor.anchor_id);
    }
}

static void on_imu(firmware_t *fw, const uwb_msg_t *in)
{
    const float acc[3] = {in->u.imu.ax, in->u.imu.ay, in->u.imu.az};
    const float gyro[3] = {in->u.imu.gx, in->u.imu.gy, in->u.imu.gz};
    const int rc = estimator_on_imu(&fw->est, in->u.imu.t_us, acc, gyro);
    if (rc == EST_OK) {
        fw->stats.imu_samples++;
    } else {
        fw->stats.time_backwards += rc == EST_ERR_TIME_BACKWARDS;
        fw_send_error(fw, (uint8_t)rc, in, 0);
    }
}

static void on_height(firmware_t *fw, const uwb_msg_t *in)
{
    const int rc = estimator_on_height(&fw->est, in->u.height.t_us, in->u.height.z, in->u.height.std);
    if (rc != EST_OK) {
        fw->stats.time_backwards += rc == EST_ERR_TIME_BACKWARDS;
        fw->stats.bad_values += rc == EST_ERR_BAD_VALUE;
        fw_send_error(fw, (uint8_t)rc, in, 0);
    }
}

/* Every other frame: a measurement of any kind, or a device -> host type arriving at the device. */
static void on_other(firmware_t *fw, const uwb_msg_t *in)
{
    uwb_meas_t meas;
    if (uwb_meas_decode(in, &meas)) {
        on_measurement(fw, in, &meas);
        return;
    }
    fw->stats.unknown_types++;
    fw_send_error(fw, UWB_ERROR_CODE_UNKNOWN_TYPE, in, 0);
}

static void dispatch(firmware_t *fw, const uwb_msg_t *in)
{
    uwb_meas_t meas;
    const uint32_t divergences = fw->est.divergences;
    if (!uwb_msg_finite(in)) {
        fw->stats.non_finite++;
        fw->stats.dropped_meas += (uint32_t)uwb_meas_decode(in, &meas);
        fw_send_error(fw, UWB_ERROR_CODE_NON_FINITE, in, 0);
        return;
    }
    switch (in->type) {
    case UWB_MSG_HELLO:
        on_hello(fw, in);
        break;
    case UWB_MSG_CONFIG:
        on_config(fw, in);
        break;
    case UWB_MSG_ANCHOR:
        on_anchor(fw, in);
        break;
    case UWB_MSG_IMU:
        on_imu(fw, in);
        break;
    case UWB_MSG_HEIGHT:
        on_height(fw, in);
        break;
    case UWB_MSG_STATS_REQ:
        on_stats_req(fw);
        break;
    case UWB_MSG_SETPOINT:
        fw_on_setpoint(fw, in);
        break;
    case UWB_MSG_RADIO:
        fw_on_radio(fw, in);
        break;
    case UWB_MSG_CLOCK_REQ:
        fw_on_clock_req(fw, in);
        break;
    default:
        on_other(fw, in);
        break;
    }
    /* The supervisor re-initialised the filter: say so (after the frame's RESULT) rather than carry on
     * silently; detail = divergences since power-up. */
    if (fw->est.divergences != divergences) {
        fw_send_error(fw, UWB_ERROR_CODE_DIVERGED, in, fw->est.divergences);
    }
}

/* frame_rx_feed's sink: one frame (or framing error) at each delimiter. */
static void on_frame(void *ctx, frame_rx_event_t ev, const uint8_t *body, size_t len)
{
    firmware_t *fw = (firmware_t *)ctx;
    uwb_msg_t msg;
    if (ev != FRAME_RX_FRAME) {
        fw->stats.framing_errors++; /* oversize, or not valid COBS */
        return;
    }
    switch (uwb_body_decode(body, len, &msg)) {
    case UWB_DECODE_OK:
        break;
    case UWB_DECODE_SHORT:
        fw->stats.framing_errors++;
        return;
    case UWB_DECODE_CRC:
        fw->stats.crc_errors++;
        return;
    case UWB_DECODE_UNKNOWN_TYPE:
        fw->stats.frames_ok++;
        fw->stats.unknown_types++;
        track_seq(fw, msg.seq);
        fw_send_error(fw, UWB_ERROR_CODE_UNKNOWN_TYPE, &msg, 0);
        return;
    case UWB_DECODE_BAD_LENGTH:
    default:
        fw->stats.frames_ok++;
        fw->stats.bad_lengths++;
        track_seq(fw, msg.seq);
        fw_send_error(fw, UWB_ERROR_CODE_BAD_LENGTH, &msg, (uint32_t)len);
        return;
    }
    fw->stats.frames_ok++;
    track_seq(fw, msg.seq);
    dispatch(fw, &msg);
}

void firmware_feed(firmware_t *fw, const uint8_t *data, size_t n)
{
    frame_rx_feed(&fw->rx, data, n, on_frame, fw);
}
