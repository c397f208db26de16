/* The firmware's SETPOINT -> CONTROL dispatch: replies, refusals, and what a CONFIG reset does to the controller. */
#include <string.h>

#include "cobs.h"
#include "controller.h"
#include "fw_wire.h"
#include "unit.h"
#include "uwb_msgs.h"

#define G 9.81

/* ------------------------------------------------------------------------ firmware dispatch */
static wire_sink_t sink;
static firmware_t fw;

static void send_msg(uint8_t type, uint16_t seq, const uwb_msg_t *m)
{
    uwb_msg_t msg = *m;
    msg.type = type;
    msg.seq = seq;
    wire_send(&fw, &msg);
}

/* The single frame the firmware wrote since the sink was cleared (0 if not exactly one). */
static int one_reply(uwb_msg_t *out)
{
    uint8_t body[UWB_MAX_BODY];
    long n;
    if (sink.len < 2 || sink.data[sink.len - 1] != 0 || memchr(sink.data, 0, sink.len - 1) != NULL) {
        return 0;
    }
    n = cobs_decode(sink.data, sink.len - 1, body, sizeof body);
    sink.len = 0;
    return n > 0 && uwb_body_decode(body, (size_t)n, out) == UWB_DECODE_OK;
}

/* Replies: CONTROL for a hover setpoint (the estimate echoed), more thrust when low, OFF. */
static void test_firmware_setpoint_control(void)
{
    uwb_msg_t m, r;
    float pos[3], vel[3], quat[4];
    memset(&m, 0, sizeof m);
    sink.len = 0;
    firmware_init(&fw, wire_sink_write, &sink, "host");
    /* hover setpoint at the power-up estimate (origin, level): thrust = m g, estimate echoed */
    m.u.setpoint.t_us = 1000;
    m.u.setpoint.mode = UWB_CONTROL_MODE_POSITION;
    send_msg(UWB_MSG_SETPOINT, 40, &m);
    CHECK(one_reply(&r));
    CHECK(r.type == UWB_MSG_CONTROL && r.u.control.setpoint_seq == 40 && r.u.control.t_us == 1000);
    CHECK(r.u.control.mode == UWB_CONTROL_MODE_POSITION);
    CHECK_NEAR(r.u.control.thrust, fw.ctl.p.mass * G, 1e-5);
    estimator_state(&fw.est, pos, vel, quat, NULL);
    CHECK(r.u.control.px == pos[0] && r.u.control.py == pos[1] && r.u.control.pz == pos[2]);
    CHECK(r.u.control.vx == vel[0] && r.u.control.qw == quat[0] && r.u.control.qz == quat[3]);
    /* 0.2 m up: more thrust */
    m.u.setpoint.t_us = 11000;
    m.u.setpoint.z = 0.2f;
    send_msg(UWB_MSG_SETPOINT, 41, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_CONTROL && r.u.control.thrust > fw.ctl.p.mass * G);
    /* OFF */
    m.u.setpoint.t_us = 21000;
    m.u.setpoint.mode = UWB_CONTROL_MODE_OFF;
    send_msg(UWB_MSG_SETPOINT, 42, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_CONTROL && r.u.control.mode == UWB_CONTROL_MODE_OFF &&
          r.u.control.thrust == 0.0f);
}

/* A fresh firmware whose controller has answered one POSITION setpoint at t_us (its reply read). */
static void start_session(uwb_msg_t *m, uint64_t t_us)
{
    uwb_msg_t r;
    memset(m, 0, sizeof *m);
    sink.len = 0;
    firmware_init(&fw, wire_sink_write, &sink, "host");
    m->u.setpoint.t_us = t_us;
    m->u.setpoint.mode = UWB_CONTROL_MODE_POSITION;
    send_msg(UWB_MSG_SETPOINT, 39, m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_CONTROL && r.u.control.setpoint_seq == 39);
}

static void test_firmware_setpoint_refusals(void)
{
    uwb_msg_t m, r;
    start_session(&m, 21000);
    /* unknown mode / reserved byte: BAD_SETPOINT */
    m.u.setpoint.t_us = 31000;
    m.u.setpoint.mode = 7;
    send_msg(UWB_MSG_SETPOINT, 43, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_ERROR && r.u.error.code == UWB_ERROR_CODE_BAD_SETPOINT &&
          r.u.error.msg_seq == 43 && r.u.error.detail == 7);
    m.u.setpoint.mode = UWB_CONTROL_MODE_POSITION;
    m.u.setpoint.reserved = 1;
    send_msg(UWB_MSG_SETPOINT, 44, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_ERROR && r.u.error.code == UWB_ERROR_CODE_BAD_SETPOINT);
    /* time going backwards */
    m.u.setpoint.reserved = 0;
    m.u.setpoint.t_us = 20000;
    send_msg(UWB_MSG_SETPOINT, 45, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_ERROR && r.u.error.code == UWB_ERROR_CODE_TIME_BACKWARDS &&
          r.u.error.msg_type == UWB_MSG_SETPOINT);
    CHECK(fw.stats.time_backwards == 1);
    /* NaN in a setpoint: NON_FINITE, no CONTROL */
    m.u.setpoint.t_us = 40000;
    m.u.setpoint.yaw = NAN;
    send_msg(UWB_MSG_SETPOINT, 46, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_ERROR && r.u.error.code == UWB_ERROR_CODE_NON_FINITE);
    CHECK(fw.stats.non_finite == 1 && fw.stats.dropped_meas == 0);
    /* still answering */
    m.u.setpoint.yaw = 0.0f;
    send_msg(UWB_MSG_SETPOINT, 47, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_CONTROL && r.u.control.setpoint_seq == 47);
}

/* CONFIG with reset: the controller forgets its time (a new flight restarts its clock) but keeps its
 * parameters; a CONTROL sent to the device is refused. */
static void test_firmware_config_reset_and_control_refused(void)
{
    uwb_msg_t m, r;
    start_session(&m, 40000);
    CHECK(fw.ctl.has_time && fw.ctl.t_us == 40000);
    memset(&m, 0, sizeof m);
    m.u.config.mode = UWB_EKF_MODE_IMU;
    m.u.config.reset = 1;
    m.u.config.std_twr = m.u.config.std_tdoa = 0.1f;
    m.u.config.a_max_twr = m.u.config.a_max_tdoa = 100.0f;
    m.u.config.gate_dt_min = 0.01f;
    m.u.config.chi2_twr = m.u.config.chi2_tdoa = 4.0f;
    m.u.config.proc_cv_acc = 1.0f;
    m.u.config.init_std_xy = m.u.config.init_std_z = 1.0f;
    m.u.config.sup_margin = 10.0f;
    m.u.config.sup_max_speed = 10.0f;
    m.u.config.sup_max_var = 50.0f;
    m.u.config.std_tof = 0.02f;
    send_msg(UWB_MSG_CONFIG, 49, &m);
    CHECK(sink.len == 0);   /* accepted: no reply */
    CHECK(!fw.ctl.has_time && fw.ctl.p.mass > 0.0f);
    {
        ctl_params_t d;
        controller_default_params(&d);
        CHECK(memcmp(&d, &fw.ctl.p, sizeof d) == 0);
    }
    memset(&m, 0, sizeof m);
    m.u.setpoint.t_us = 0;
    m.u.setpoint.mode = UWB_CONTROL_MODE_POSITION;
    send_msg(UWB_MSG_SETPOINT, 50, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_CONTROL && r.u.control.setpoint_seq == 50);
    /* a CONTROL (device -> host type) sent to the device is refused as UNKNOWN_TYPE */
    memset(&m, 0, sizeof m);
    send_msg(UWB_MSG_CONTROL, 51, &m);
    CHECK(one_reply(&r) && r.type == UWB_MSG_ERROR && r.u.error.code == UWB_ERROR_CODE_UNKNOWN_TYPE);
}

int main(void)
{
    RUN(test_firmware_setpoint_control);
    RUN(test_firmware_setpoint_refusals);
    RUN(test_firmware_config_reset_and_control_refused);
    return UNIT_DONE();
}
