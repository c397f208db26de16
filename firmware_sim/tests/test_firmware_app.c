/* The firmware application end to end in memory: frames in, frames out, every refusal accounted. */
#include <stdlib.h>
#include <string.h>

#include "fw_wire.h"
#include "unit.h"

static wire_sink_t sink;
static firmware_t fw;

static void send(const uwb_msg_t *msg)
{
    wire_send(&fw, msg);
}

/* Decode everything in the sink; returns the number of frames, last one of `type` in *out. */
static int replies(uint8_t type, uwb_msg_t *out, int *count_of_type)
{
    size_t pos = 0;
    int frames = 0;
    uwb_msg_t msg;
    *count_of_type = 0;
    while (wire_next(&sink, &pos, &msg)) {
        frames++;
        if (msg.type == type) {
            *out = msg;
            (*count_of_type)++;
        }
    }
    return frames;
}

static void reset(void)
{
    sink.len = 0;
    firmware_init(&fw, wire_sink_write, &sink, "test");
}

static uwb_msg_t twr(uint16_t seq, uint64_t t, uint8_t id, float r)
{
    uwb_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_TWR;
    m.seq = seq;
    m.u.twr.t_us = t;
    m.u.twr.anchor_id = id;
    m.u.twr.range = r;
    return m;
}

static uwb_msg_t anchor(uint16_t seq, uint8_t id, float x, float y, float z)
{
    uwb_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_ANCHOR;
    m.seq = seq;
    m.u.anchor.anchor_id = id;
    m.u.anchor.x = x;
    m.u.anchor.y = y;
    m.u.anchor.z = z;
    return m;
}

static void test_hello(void)
{
    uwb_msg_t m, r;
    int n;
    reset();
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_HELLO;
    m.u.hello.nonce = 0xCAFEu;
    send(&m);
    replies(UWB_MSG_HELLO_REPLY, &r, &n);
    CHECK(n == 1);
    CHECK(r.u.hello_reply.nonce == 0xCAFEu);
    CHECK(r.u.hello_reply.proto_version == UWB_PROTO_VERSION);
    CHECK(r.u.hello_reply.model_hash == bias_model_compiled.hash);
    CHECK(memcmp(r.u.hello_reply.target, "test", 4) == 0);
}

static void test_measurement_result_and_refusals(void)
{
    uwb_msg_t m, r;
    int n;
    unsigned k;
    reset();
    send((m = anchor(0, 0, 0.0f, 0.0f, 3.0f), &m));
    send((m = twr(1, 1000, 0, 3.0f), &m));
    replies(UWB_MSG_RESULT, &r, &n);
    CHECK(n == 1);
    CHECK(r.u.result.meas_seq == 1);
    CHECK(r.u.result.kind == UWB_MEAS_KIND_TWR);
    CHECK(r.u.result.t_us == 1000);
    /* unknown anchor -> ERROR, counted, no RESULT */
    sink.len = 0;
    send((m = twr(2, 2000, 5, 3.0f), &m));
    replies(UWB_MSG_ERROR, &r, &n);
    CHECK(n == 1 && r.u.error.code == UWB_ERROR_CODE_UNKNOWN_ANCHOR && r.u.error.msg_seq == 2);
    /* time going backwards */
    sink.len = 0;
    send((m = twr(3, 500, 0, 3.0f), &m));
    replies(UWB_MSG_ERROR, &r, &n);
    CHECK(n == 1 && r.u.error.code == UWB_ERROR_CODE_TIME_BACKWARDS);
    /* NaN range */
    sink.len = 0;
    send((m = twr(4, 3000, 0, NAN), &m));
    replies(UWB_MSG_ERROR, &r, &n);
    CHECK(n == 1 && r.u.error.code == UWB_ERROR_CODE_NON_FINITE);
    /* any 8-bit id until the table is full (one anchor is set above): the 16th new id is refused */
    for (k = 0; k < ESTIMATOR_MAX_ANCHORS; k++) {
        sink.len = 0;
        send((m = anchor((uint16_t)(5 + k), (uint8_t)(200 + k), 1.0f, 1.0f, 1.0f), &m));
        replies(UWB_MSG_ERROR, &r, &n);
        CHECK(n == (k + 1 == ESTIMATOR_MAX_ANCHORS ? 1 : 0));
    }
    CHECK(r.u.error.code == UWB_ERROR_CODE_BAD_ANCHOR_ID && r.u.error.detail == 215u);
    CHECK(fw.stats.unknown_anchors == 2);   /* the measurement above and this ANCHOR frame */
    CHECK(fw.stats.time_backwards == 1);
    CHECK(fw.stats.non_finite == 1);
    CHECK(fw.stats.dropped_meas == 3);
    CHECK(fw.stats.results == 1);
}

static void test_bad_config_refused_and_state_kept(void)
{
    uwb_msg_t m, r;
    int n;
    estimator_config_t before;
    reset();
    before = fw.est.cfg;
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_CONFIG;
    m.seq = 1;
    m.u.config.mode = 1;
    m.u.config.stages = 7;
    m.u.config.std_twr = -0.1f; /* invalid */
    m.u.config.std_tdoa = 0.15f;
    m.u.config.a_max_twr = 1.0f;
    m.u.config.a_max_tdoa = 1.0f;
    m.u.config.gate_dt_min = 0.01f;
    m.u.config.chi2_twr = 3.8f;
    m.u.config.chi2_tdoa = 3.8f;
    m.u.config.proc_cv_acc = 1.0f;
    m.u.config.init_std_xy = 1.0f;
    m.u.config.init_std_z = 1.0f;
    m.u.config.sup_margin = 10.0f;
    m.u.config.sup_max_speed = 10.0f;
    m.u.config.sup_max_var = 50.0f;
    m.u.config.std_tof = 0.02f;
    send(&m);
    replies(UWB_MSG_ERROR, &r, &n);
    CHECK(n == 1 && r.u.error.code == UWB_ERROR_CODE_BAD_CONFIG);
    CHECK(memcmp(&before, &fw.est.cfg, sizeof before) == 0);
    CHECK(fw.stats.bad_configs == 1);
    /* same message with a valid value is applied */
    sink.len = 0;
    m.u.config.std_twr = 0.1f;
    m.seq = 2;
    send(&m);
    replies(UWB_MSG_ERROR, &r, &n);
    CHECK(n == 0);
    CHECK(fw.est.cfg.std_twr == 0.1f && fw.est.cfg.mode == 1);
}

static void test_garbage_is_counted_and_valid_frames_survive(void)
{
    uint8_t junk[4096];
    uwb_msg_t m, r;
    int n, i;
    unsigned seed = 99;
    reset();
    send((m = anchor(0, 0, 0.0f, 0.0f, 3.0f), &m));
    for (i = 0; i < 256; i++) {
        size_t k;
        for (k = 0; k < sizeof junk; k++) {
            seed = seed * 1664525u + 1013904223u;
            junk[k] = (uint8_t)(seed >> 24);
        }
        firmware_feed(&fw, junk, sizeof junk);
    }
    /* a delimiter ends whatever partial garbage is pending, then a valid frame */
    firmware_feed(&fw, (const uint8_t *)"\0", 1);
    sink.len = 0;
    send((m = twr(60000, 5000, 0, 3.0f), &m));
    replies(UWB_MSG_RESULT, &r, &n);
    CHECK(n == 1 && r.u.result.meas_seq == 60000);
    CHECK(fw.stats.crc_errors + fw.stats.framing_errors > 1000);
}

static void test_seq_gaps_counted(void)
{
    uwb_msg_t m;
    reset();
    send((m = anchor(10, 0, 0.0f, 0.0f, 3.0f), &m));
    send((m = anchor(11, 1, 1.0f, 0.0f, 3.0f), &m));
    send((m = anchor(15, 2, 2.0f, 0.0f, 3.0f), &m)); /* 12, 13, 14 missing */
    CHECK(fw.stats.seq_gaps == 3);
}

int main(void)
{
    RUN(test_hello);
    RUN(test_measurement_result_and_refusals);
    RUN(test_bad_config_refused_and_state_kept);
    RUN(test_garbage_is_counted_and_valid_frames_survive);
    RUN(test_seq_gaps_counted);
    return UNIT_DONE();
}
