/* SETPOINT frames: the closed loop's position controller on the current estimate (docs/closed-loop.md). */
#include <string.h>

#include "fw_internal.h"
#include "platform.h"

/* One control step on the current estimate; answered by CONTROL (or ERROR). */
void fw_on_setpoint(firmware_t *fw, const uwb_msg_t *in)
{
    const uwb_setpoint_t *s = &in->u.setpoint;
    ctl_setpoint_t sp;
    ctl_estimate_t est;
    ctl_output_t co;
    uwb_msg_t out;
    uint32_t t0, t1;
    int rc;
    if (s->mode > UWB_CONTROL_MODE_POSITION || s->reserved != 0) {
        fw_send_error(fw, UWB_ERROR_CODE_BAD_SETPOINT, in, s->mode);
        return;
    }
    sp.mode = s->mode;
    sp.pos[0] = s->x;
    sp.pos[1] = s->y;
    sp.pos[2] = s->z;
    sp.vel[0] = s->vx;
    sp.vel[1] = s->vy;
    sp.vel[2] = s->vz;
    sp.acc[0] = s->ax;
    sp.acc[1] = s->ay;
    sp.acc[2] = s->az;
    sp.yaw = s->yaw;
    t0 = platform_cost_now();
    estimator_state(&fw->est, est.pos, est.vel, est.quat, NULL);
    rc = controller_step(&fw->ctl, s->t_us, &sp, &est, &co);
    t1 = platform_cost_now();
    if (rc != CTL_OK) {
        fw->stats.time_backwards++;
        fw_send_error(fw, (uint8_t)rc, in, 0);
        return;
    }
    memset(&out, 0, sizeof out);
    out.type = UWB_MSG_CONTROL;
    out.u.control.setpoint_seq = in->seq;
    out.u.control.mode = co.mode;
    out.u.control.flags = co.flags;
    out.u.control.t_us = s->t_us;
    out.u.control.thrust = co.thrust;
    out.u.control.rate_x = co.rate[0];
    out.u.control.rate_y = co.rate[1];
    out.u.control.rate_z = co.rate[2];
    out.u.control.px = est.pos[0];
    out.u.control.py = est.pos[1];
    out.u.control.pz = est.pos[2];
    out.u.control.vx = est.vel[0];
    out.u.control.vy = est.vel[1];
    out.u.control.vz = est.vel[2];
    out.u.control.qw = est.quat[0];
    out.u.control.qx = est.quat[1];
    out.u.control.qy = est.quat[2];
    out.u.control.qz = est.quat[3];
    out.u.control.compute = t1 - t0;
    fw_send_msg(fw, &out);
}
