/* Position controller: outputs by hand, refusals, and closed-loop flights against a small rigid-body
 * model (thrust lag, body-rate loop lag, drag, ground) with the true state as the estimate; plus the
 * firmware's SETPOINT -> CONTROL dispatch. */
#include <string.h>

#include "cobs.h"
#include "controller.h"
#include "fw_wire.h"
#include "unit.h"
#include "uwb_msgs.h"

#define G 9.81
#define DEG (3.14159265358979 / 180.0)

/* ------------------------------------------------------------------------------ vehicle model */
typedef struct {
    double mass, drag;           /* kg, linear drag [N/(m/s)] */
    double tau_thrust, tau_rate; /* first-order lags of collective thrust and of the body-rate loop [s] */
    double p[3], v[3], q[4], w[3], thrust;
} vehicle_t;

static void vehicle_init(vehicle_t *s, double mass)
{
    memset(s, 0, sizeof *s);
    s->mass = mass;
    s->drag = 0.006;
    s->tau_thrust = 0.03;
    s->tau_rate = 0.04;
    s->q[0] = 1.0;
}

static void rot(const double q[4], double R[3][3])
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0][0] = 1 - 2 * (y * y + z * z);
    R[0][1] = 2 * (x * y - w * z);
    R[0][2] = 2 * (x * z + w * y);
    R[1][0] = 2 * (x * y + w * z);
    R[1][1] = 1 - 2 * (x * x + z * z);
    R[1][2] = 2 * (y * z - w * x);
    R[2][0] = 2 * (x * z - w * y);
    R[2][1] = 2 * (y * z + w * x);
    R[2][2] = 1 - 2 * (x * x + y * y);
}

static double tilt_of(const double q[4])
{
    double R[3][3];
    rot(q, R);
    return acos(R[2][2] > 1.0 ? 1.0 : R[2][2]);
}

/* Semi-implicit Euler step of dt under the command (thrust [N], body rates [rad/s]). */
static void vehicle_step(vehicle_t *s, const ctl_output_t *u, double dt)
{
    double R[3][3], a[3], dq[4], n;
    int i;
    s->thrust += (u->thrust - s->thrust) * dt / s->tau_thrust;
    for (i = 0; i < 3; i++) {
        s->w[i] += (u->rate[i] - s->w[i]) * dt / s->tau_rate;
    }
    rot(s->q, R);
    for (i = 0; i < 3; i++) {
        a[i] = s->thrust / s->mass * R[i][2] - s->drag / s->mass * s->v[i];
    }
    a[2] -= G;
    for (i = 0; i < 3; i++) {
        s->v[i] += a[i] * dt;
        s->p[i] += s->v[i] * dt;
    }
    if (s->p[2] <= 0.0) { /* on the ground: it holds the vehicle up and stops it */
        s->p[2] = 0.0;
        if (s->v[2] < 0.0) {
            s->v[0] = s->v[1] = s->v[2] = 0.0;
        }
    }
    /* q <- q (x) exp(w dt / 2), first order, renormalised */
    dq[0] = -0.5 * dt * (s->q[1] * s->w[0] + s->q[2] * s->w[1] + s->q[3] * s->w[2]);
    dq[1] = 0.5 * dt * (s->q[0] * s->w[0] + s->q[2] * s->w[2] - s->q[3] * s->w[1]);
    dq[2] = 0.5 * dt * (s->q[0] * s->w[1] + s->q[3] * s->w[0] - s->q[1] * s->w[2]);
    dq[3] = 0.5 * dt * (s->q[0] * s->w[2] + s->q[1] * s->w[1] - s->q[2] * s->w[0]);
    n = 0.0;
    for (i = 0; i < 4; i++) {
        s->q[i] += dq[i];
        n += s->q[i] * s->q[i];
    }
    n = sqrt(n);
    for (i = 0; i < 4; i++) {
        s->q[i] /= n;
    }
}

static void truth_estimate(const vehicle_t *s, ctl_estimate_t *e)
{
    int i;
    for (i = 0; i < 3; i++) {
        e->pos[i] = (float)s->p[i];
        e->vel[i] = (float)s->v[i];
    }
    for (i = 0; i < 4; i++) {
        e->quat[i] = (float)s->q[i];
    }
}

typedef void (*setpoint_fn)(double t, ctl_setpoint_t *sp);

typedef struct {
    double max_tilt, t_reach_half_m, rmse_after, max_err_after, final_err;
    int n_after;
    uint8_t flags_seen;
} flight_stats_t;

/* Fly for `duration` s at 100 Hz control / 1 kHz physics; tracking statistics from t_after on. */
static flight_stats_t fly(vehicle_t *s, setpoint_fn setpoint, double duration, double t_after)
{
    controller_t c;
    ctl_params_t p;
    ctl_output_t u;
    flight_stats_t st;
    double se = 0.0;
    int k, j;
    memset(&st, 0, sizeof st);
    memset(&u, 0, sizeof u);
    st.t_reach_half_m = -1.0;
    controller_default_params(&p);
    controller_init(&c, &p);
    for (k = 0; k * 0.01 < duration; k++) {
        double t = k * 0.01, e2 = 0.0;
        ctl_setpoint_t sp;
        ctl_estimate_t est;
        int i;
        setpoint(t, &sp);
        truth_estimate(s, &est);
        CHECK(controller_step(&c, (uint64_t)k * 10000u, &sp, &est, &u) == CTL_OK);
        st.flags_seen |= u.flags;
        for (i = 0; i < 3; i++) {
            e2 += (s->p[i] - sp.pos[i]) * (s->p[i] - sp.pos[i]);
        }
        if (t >= t_after) {
            se += e2;
            st.n_after++;
            if (sqrt(e2) > st.max_err_after) {
                st.max_err_after = sqrt(e2);
            }
        }
        st.final_err = sqrt(e2);
        for (j = 0; j < 10; j++) {
            vehicle_step(s, &u, 0.001);
            if (tilt_of(s->q) > st.max_tilt) {
                st.max_tilt = tilt_of(s->q);
            }
            if (st.t_reach_half_m < 0.0 && s->p[2] >= 0.5) {
                st.t_reach_half_m = t + (j + 1) * 0.001;
            }
        }
    }
    st.rmse_after = st.n_after ? sqrt(se / st.n_after) : 0.0;
    return st;
}

static void sp_zero(ctl_setpoint_t *sp)
{
    memset(sp, 0, sizeof *sp);
    sp->mode = CTL_MODE_POSITION;
}

/* Take-off: z ramps 0 -> 1 m at 0.5 m/s, then hover. */
static void sp_takeoff(double t, ctl_setpoint_t *sp)
{
    sp_zero(sp);
    sp->pos[2] = (float)(t < 2.0 ? 0.5 * t : 1.0);
    sp->vel[2] = (float)(t < 2.0 ? 0.5 : 0.0);
}

/* Hover at 1 m, then a 1 m step in x at t = 1 s (no feed-forward). */
static void sp_step(double t, ctl_setpoint_t *sp)
{
    sp_zero(sp);
    sp->pos[0] = (float)(t < 1.0 ? 0.0 : 1.0);
    sp->pos[2] = 1.0f;
}

/* The paper's circle: radius 1.5 m at 0.375 m/s, z = 1 m, with velocity and acceleration feed-forward. */
static void sp_circle(double t, ctl_setpoint_t *sp)
{
    const double r = 1.5, v = 0.375, w = v / r;
    sp_zero(sp);
    sp->pos[0] = (float)(r * cos(w * t));
    sp->pos[1] = (float)(r * sin(w * t));
    sp->pos[2] = 1.0f;
    sp->vel[0] = (float)(-v * sin(w * t));
    sp->vel[1] = (float)(v * cos(w * t));
    sp->acc[0] = (float)(-v * w * cos(w * t));
    sp->acc[1] = (float)(-v * w * sin(w * t));
}

/* ---------------------------------------------------------------------------------- unit tests */
static void level_at(ctl_estimate_t *e, float x, float y, float z)
{
    memset(e, 0, sizeof *e);
    e->pos[0] = x;
    e->pos[1] = y;
    e->pos[2] = z;
    e->quat[0] = 1.0f;
}

static void test_params(void)
{
    ctl_params_t p;
    controller_default_params(&p);
    CHECK(controller_params_valid(&p));
    p.mass = 0.0f;
    CHECK(!controller_params_valid(&p));
    controller_default_params(&p);
    p.max_tilt = 1.6f;
    CHECK(!controller_params_valid(&p));
    controller_default_params(&p);
    p.kp[1] = NAN;
    CHECK(!controller_params_valid(&p));
    controller_default_params(&p);
    p.rate_max[2] = 0.0f;
    CHECK(!controller_params_valid(&p));
}

static void test_hover_output(void)
{
    controller_t c;
    ctl_params_t p;
    ctl_setpoint_t sp;
    ctl_estimate_t e;
    ctl_output_t u;
    controller_default_params(&p);
    controller_init(&c, &p);
    sp_zero(&sp);
    sp.pos[2] = 1.0f;
    level_at(&e, 0.0f, 0.0f, 1.0f);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK(u.mode == CTL_MODE_POSITION && u.flags == 0);
    CHECK_NEAR(u.thrust, p.mass * G, 1e-5);
    CHECK_NEAR(u.rate[0], 0.0, 1e-6);
    CHECK_NEAR(u.rate[1], 0.0, 1e-6);
    CHECK_NEAR(u.rate[2], 0.0, 1e-6);
    /* 0.1 m low: thrust rises by m kp_z 0.1 (first step: no integral yet) */
    level_at(&e, 0.0f, 0.0f, 0.9f);
    CHECK(controller_step(&c, 10000, &sp, &e, &u) == CTL_OK);
    CHECK_NEAR(u.thrust, p.mass * (G + p.kp[2] * 0.1 + p.ki[2] * 0.1 * 0.01), 1e-5);
    CHECK_NEAR(c.integ[2], 0.1 * 0.01, 1e-7);
}

static void test_attitude_error_to_rates(void)
{
    controller_t c;
    ctl_params_t p;
    ctl_setpoint_t sp;
    ctl_estimate_t e;
    ctl_output_t u;
    const double a = 0.2;
    controller_default_params(&p);
    controller_init(&c, &p);
    sp_zero(&sp);
    sp.pos[2] = 1.0f;
    /* rolled by +0.2 rad about x: the command rolls back, e_R = sin(a) about x */
    level_at(&e, 0.0f, 0.0f, 1.0f);
    e.quat[0] = (float)cos(a / 2);
    e.quat[1] = (float)sin(a / 2);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK_NEAR(u.rate[0], -p.k_att[0] * sin(a), 1e-4);
    CHECK_NEAR(u.rate[1], 0.0, 1e-5);
    CHECK_NEAR(u.rate[2], 0.0, 1e-5);
    CHECK_NEAR(u.thrust, p.mass * G * cos(a), 1e-4);   /* projected on the tilted body z */
    /* yaw setpoint +0.5 rad from level: positive yaw rate k sin(0.5) */
    sp.yaw = 0.5f;
    level_at(&e, 0.0f, 0.0f, 1.0f);
    controller_init(&c, &p);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK_NEAR(u.rate[2], p.k_att[2] * sin(0.5), 1e-4);
    CHECK_NEAR(u.rate[0], 0.0, 1e-5);
    /* 0.1 m behind in x: pitch forward (positive pitch rate about body y tilts thrust toward +x) */
    sp.yaw = 0.0f;
    level_at(&e, -0.1f, 0.0f, 1.0f);
    controller_init(&c, &p);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK(u.rate[1] > 0.0f);
    CHECK_NEAR(u.rate[1], p.k_att[1] * sin(atan(p.kp[0] * 0.1 / G)), 1e-3);
}

static void test_limits(void)
{
    controller_t c;
    ctl_params_t p;
    ctl_setpoint_t sp;
    ctl_estimate_t e;
    ctl_output_t u;
    controller_default_params(&p);
    controller_init(&c, &p);
    /* 5 m up: thrust clipped */
    sp_zero(&sp);
    sp.pos[2] = 6.0f;
    level_at(&e, 0.0f, 0.0f, 1.0f);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK(u.flags & CTL_FLAG_THRUST_SATURATED);
    CHECK_NEAR(u.thrust, p.thrust_max, 1e-6);
    /* 5 m down: vertical acceleration floored at a_z_min */
    sp.pos[2] = -4.0f;
    controller_init(&c, &p);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK(u.flags & CTL_FLAG_TILT_LIMITED);
    CHECK_NEAR(u.thrust, p.mass * p.a_z_min, 1e-5);
    /* 10 m sideways: tilt limited, the roll command equals k sin(max_tilt) */
    sp_zero(&sp);
    sp.pos[1] = 10.0f;
    sp.pos[2] = 1.0f;
    controller_init(&c, &p);
    CHECK(controller_step(&c, 0, &sp, &e, &u) == CTL_OK);
    CHECK(u.flags & CTL_FLAG_TILT_LIMITED);
    CHECK_NEAR(u.rate[0], -p.k_att[0] * sin(p.max_tilt), 1e-3);
    /* a large attitude error: the rate command is clipped */
    level_at(&e, 0.0f, 10.0f, 1.0f);
    e.quat[0] = (float)cos(1.2 / 2);
    e.quat[1] = (float)sin(1.2 / 2);
    sp.pos[1] = 10.0f;
    CHECK(controller_step(&c, 10000, &sp, &e, &u) == CTL_OK);
    CHECK(u.flags & CTL_FLAG_RATE_LIMITED);
    CHECK_NEAR(u.rate[0], -p.rate_max[0], 1e-6);
    /* integrator bound */
    level_at(&e, 0.0f, 0.0f, 1.0f);
    sp_zero(&sp);
    sp.pos[0] = 0.2f;
    sp.pos[2] = 1.0f;
    controller_init(&c, &p);
    {
        int k;
        uint8_t seen = 0;
        for (k = 0; k < 400; k++) {
            CHECK(controller_step(&c, (uint64_t)k * 10000u, &sp, &e, &u) == CTL_OK);
            seen |= u.flags;
        }
        CHECK(seen & CTL_FLAG_INTEGRATOR_LIMITED);
        CHECK_NEAR(c.integ[0], p.i_max[0], 1e-6);
    }
}

static void test_off_nonfinite_and_time(void)
{
    controller_t c;
    ctl_params_t p;
    ctl_setpoint_t sp;
    ctl_estimate_t e;
    ctl_output_t u;
    controller_default_params(&p);
    controller_init(&c, &p);
    sp_zero(&sp);
    sp.pos[2] = 1.0f;
    level_at(&e, 0.0f, 0.0f, 0.9f);
    CHECK(controller_step(&c, 100000, &sp, &e, &u) == CTL_OK);
    CHECK(controller_step(&c, 110000, &sp, &e, &u) == CTL_OK);
    CHECK(c.integ[2] > 0.0f);
    /* time backwards: refused, nothing changes */
    {
        controller_t before = c;
        CHECK(controller_step(&c, 109999, &sp, &e, &u) == CTL_ERR_TIME_BACKWARDS);
        CHECK(memcmp(&before, &c, sizeof c) == 0);
    }
    /* the same time again is fine (dt = 0: no integration) */
    {
        float i0 = c.integ[2];
        CHECK(controller_step(&c, 110000, &sp, &e, &u) == CTL_OK);
        CHECK(c.integ[2] == i0);
    }
    /* OFF: zero output, integrals reset */
    sp.mode = CTL_MODE_OFF;
    CHECK(controller_step(&c, 120000, &sp, &e, &u) == CTL_OK);
    CHECK(u.mode == CTL_MODE_OFF && u.thrust == 0.0f && u.rate[0] == 0.0f && u.rate[1] == 0.0f &&
          u.rate[2] == 0.0f && u.flags == 0);
    CHECK(c.integ[0] == 0.0f && c.integ[1] == 0.0f && c.integ[2] == 0.0f);
    /* back to POSITION after OFF: the gap is not integrated */
    sp.mode = CTL_MODE_POSITION;
    CHECK(controller_step(&c, 5000000, &sp, &e, &u) == CTL_OK);
    CHECK(c.integ[2] == 0.0f);
    /* a gap longer than dt_max is not integrated either */
    CHECK(controller_step(&c, 5000000 + 200000, &sp, &e, &u) == CTL_OK);
    CHECK(c.integ[2] == 0.0f);
    /* non-finite estimate or a zero quaternion: motors off, reported as OFF */
    e.vel[1] = INFINITY;
    CHECK(controller_step(&c, 5210000, &sp, &e, &u) == CTL_OK);
    CHECK(u.mode == CTL_MODE_OFF && u.thrust == 0.0f);
    level_at(&e, 0.0f, 0.0f, 0.5f);
    e.quat[0] = 0.0f;
    CHECK(controller_step(&c, 5220000, &sp, &e, &u) == CTL_OK);
    CHECK(u.mode == CTL_MODE_OFF && u.thrust == 0.0f);
    /* a non-unit quaternion is normalised */
    level_at(&e, 0.0f, 0.0f, 1.0f);
    e.quat[0] = 2.0f;
    CHECK(controller_step(&c, 5230000, &sp, &e, &u) == CTL_OK);
    CHECK(u.mode == CTL_MODE_POSITION);
    CHECK_NEAR(u.thrust, p.mass * G, 1e-4);
}

/* ------------------------------------------------------------------- against the vehicle model */
static void test_takeoff_and_hover_mass_mismatch(void)
{
    const double masses[3] = {0.027, 0.032, 0.034};
    int i;
    for (i = 0; i < 3; i++) {
        vehicle_t s;
        flight_stats_t st;
        vehicle_init(&s, masses[i]);
        st = fly(&s, sp_takeoff, 12.0, 8.0);
        printf("    mass %.3f kg: 0.5 m after %.2f s, max tilt %.2f deg, hover error %.4f m (max %.4f)\n",
               masses[i], st.t_reach_half_m, st.max_tilt / DEG, st.rmse_after, st.max_err_after);
        CHECK(st.t_reach_half_m > 0.0 && st.t_reach_half_m < 1.6);
        CHECK(st.max_tilt < 1.0 * DEG);
        CHECK(st.max_err_after < 0.01);   /* the integral removed the mass mismatch */
        CHECK(s.p[2] > 0.99 && s.p[2] < 1.01);
    }
}

static void test_step_response(void)
{
    vehicle_t s;
    flight_stats_t st;
    vehicle_init(&s, 0.032);
    s.p[2] = 1.0;
    st = fly(&s, sp_step, 10.0, 8.0);
    printf("    1 m step: max tilt %.1f deg, error after 8 s %.4f m\n", st.max_tilt / DEG, st.max_err_after);
    CHECK(st.max_tilt < 25.0 * DEG + 3.0 * DEG); /* the tilt bound holds up to the attitude-loop lag */
    CHECK(st.max_tilt > 10.0 * DEG);             /* it does pitch to get there */
    CHECK(st.flags_seen & CTL_FLAG_TILT_LIMITED);
    CHECK(st.max_err_after < 0.02);
    {
        /* overshoot of a critically damped loop (plus integral) stays small */
        vehicle_t s2;
        controller_t c;
        ctl_params_t p;
        ctl_output_t u;
        double x_max = 0.0;
        int k, j;
        vehicle_init(&s2, 0.032);
        s2.p[2] = 1.0;
        controller_default_params(&p);
        controller_init(&c, &p);
        for (k = 0; k < 600; k++) {
            ctl_setpoint_t sp;
            ctl_estimate_t e;
            sp_step(k * 0.01, &sp);
            truth_estimate(&s2, &e);
            controller_step(&c, (uint64_t)k * 10000u, &sp, &e, &u);
            for (j = 0; j < 10; j++) {
                vehicle_step(&s2, &u, 0.001);
            }
            if (s2.p[0] > x_max) {
                x_max = s2.p[0];
            }
        }
        printf("    1 m step: x peak %.3f m\n", x_max);
        CHECK(x_max < 1.10);
        CHECK(fabs(s2.p[2] - 1.0) < 0.02);
    }
}

static void test_circle_tracking(void)
{
    vehicle_t s;
    flight_stats_t st;
    vehicle_init(&s, 0.030);
    s.p[0] = 1.5;
    s.p[2] = 1.0;
    s.v[1] = 0.375;   /* already on the circle */
    s.thrust = 0.030 * G;
    st = fly(&s, sp_circle, 30.0, 5.0);
    printf("    circle r 1.5 m at 0.375 m/s: tracking RMSE %.4f m, max %.4f m, max tilt %.2f deg\n",
           st.rmse_after, st.max_err_after, st.max_tilt / DEG);
    CHECK(st.rmse_after < 0.02);
    CHECK(st.max_err_after < 0.03);
    CHECK(st.max_tilt < 3.0 * DEG);
}

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
    /* CONFIG with reset: the controller forgets its time (a new flight restarts its clock) but keeps
     * its parameters */
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
    RUN(test_params);
    RUN(test_hover_output);
    RUN(test_attitude_error_to_rates);
    RUN(test_limits);
    RUN(test_off_nonfinite_and_time);
    RUN(test_takeoff_and_hover_mass_mismatch);
    RUN(test_step_response);
    RUN(test_circle_tracking);
    RUN(test_firmware_setpoint_control);
    return UNIT_DONE();
}
