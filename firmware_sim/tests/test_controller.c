/* Position controller: outputs by hand, limits and refusals. Closed-loop flights against a vehicle model are
 * in test_controller_flight.c, the firmware's SETPOINT -> CONTROL dispatch in test_firmware_setpoint.c. */
#include <string.h>

#include "controller.h"
#include "unit.h"

#define G 9.81

static void sp_zero(ctl_setpoint_t *sp)
{
    memset(sp, 0, sizeof *sp);
    sp->mode = CTL_MODE_POSITION;
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

int main(void)
{
    RUN(test_params);
    RUN(test_hover_output);
    RUN(test_attitude_error_to_rates);
    RUN(test_limits);
    RUN(test_off_nonfinite_and_time);
    return UNIT_DONE();
}
