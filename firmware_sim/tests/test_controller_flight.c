/* Position controller: closed-loop flights against a small rigid-body model (thrust lag, body-rate loop lag,
 * drag, ground) with the true state as the estimate: take-off with a mass mismatch, a step, the paper's circle. */
#include <string.h>

#include "controller.h"
#include "unit.h"

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

int main(void)
{
    RUN(test_takeoff_and_hover_mass_mismatch);
    RUN(test_step_response);
    RUN(test_circle_tracking);
    return UNIT_DONE();
}
