#include <math.h>
#include <string.h>

#include "controller.h"
#include "trig.h"

#define CTL_GRAVITY 9.81f

void controller_default_params(ctl_params_t *p)
{
    /* Position loop: critically damped, omega_n = 2.5 rad/s horizontally and 3.5 rad/s vertically,
     * slow enough that the attitude loop (k_att 10/s) and the ~10 ms UWB/EKF noise do not dominate,
     * fast enough to follow 0.375 m/s circles with centimetre lag. Small integrals remove the
     * steady-state error of a mass mismatch (27-34 g vehicles against a 32 g model). */
    static const ctl_params_t defaults = {
        0.032f,                      /* mass */
        {6.25f, 6.25f, 12.25f},      /* kp */
        {5.0f, 5.0f, 7.0f},          /* kd */
        {2.0f, 2.0f, 6.0f},          /* ki */
        {0.2f, 0.2f, 0.5f},          /* i_max: z covers a 0.027 kg vehicle (ki i_max = 6 m/s^2) */
        0.25f,                       /* i_err_max */
        {10.0f, 10.0f, 4.0f},        /* k_att */
        {8.0f, 8.0f, 3.0f},          /* rate_max */
        0.4363323f,                  /* max_tilt: 25 deg */
        2.0f,                        /* a_z_min */
        0.6f,                        /* thrust_max: 4 x 0.15 N */
        0.1f                         /* dt_max */
    };
    *p = defaults;
}

static int finite_pos(float x)
{
    return isfinite(x) && x > 0.0f;
}

int controller_params_valid(const ctl_params_t *p)
{
    int i;
    if (!finite_pos(p->mass) || !finite_pos(p->thrust_max) || !finite_pos(p->a_z_min) ||
        !finite_pos(p->i_err_max) ||
        !finite_pos(p->dt_max) || !finite_pos(p->max_tilt) || !(p->max_tilt < 1.5707963f)) {
        return 0;
    }
    for (i = 0; i < 3; i++) {
        if (!isfinite(p->kp[i]) || p->kp[i] < 0.0f || !isfinite(p->kd[i]) || p->kd[i] < 0.0f ||
            !isfinite(p->ki[i]) || p->ki[i] < 0.0f || !isfinite(p->i_max[i]) || p->i_max[i] < 0.0f ||
            !isfinite(p->k_att[i]) || p->k_att[i] < 0.0f || !finite_pos(p->rate_max[i])) {
            return 0;
        }
    }
    return 1;
}

void controller_init(controller_t *c, const ctl_params_t *p)
{
    const ctl_params_t keep = *p; /* p may point into c (re-initialisation with its own parameters) */
    memset(c, 0, sizeof *c);
    c->p = keep;
}

static float clampf(float x, float lo, float hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}

static int estimate_finite(const ctl_estimate_t *e)
{
    int i;
    for (i = 0; i < 3; i++) {
        if (!isfinite(e->pos[i]) || !isfinite(e->vel[i])) {
            return 0;
        }
    }
    for (i = 0; i < 4; i++) {
        if (!isfinite(e->quat[i])) {
            return 0;
        }
    }
    return 1;
}

/* Rotation matrix (body -> world) of a quaternion, normalised here; 0 if the norm is ~0. */
static int quat_to_rot(const float q_in[4], float R[3][3])
{
    float n = sqrtf(q_in[0] * q_in[0] + q_in[1] * q_in[1] + q_in[2] * q_in[2] + q_in[3] * q_in[3]);
    float w, x, y, z;
    if (!(n > 1e-6f)) {
        return 0;
    }
    w = q_in[0] / n;
    x = q_in[1] / n;
    y = q_in[2] / n;
    z = q_in[3] / n;
    R[0][0] = 1.0f - 2.0f * (y * y + z * z);
    R[0][1] = 2.0f * (x * y - w * z);
    R[0][2] = 2.0f * (x * z + w * y);
    R[1][0] = 2.0f * (x * y + w * z);
    R[1][1] = 1.0f - 2.0f * (x * x + z * z);
    R[1][2] = 2.0f * (y * z - w * x);
    R[2][0] = 2.0f * (x * z - w * y);
    R[2][1] = 2.0f * (y * z + w * x);
    R[2][2] = 1.0f - 2.0f * (x * x + y * y);
    return 1;
}

static void cross(const float a[3], const float b[3], float out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static void motors_off(controller_t *c, uint8_t mode, ctl_output_t *out)
{
    memset(out, 0, sizeof *out);
    out->mode = mode;
    c->integ[0] = c->integ[1] = c->integ[2] = 0.0f;
    c->was_flying = 0;
}

/* Desired acceleration (world), with the integral of the position error. A long gap (the host paused)
 * is not integrated: it says nothing about a steady-state error. Returns the limit flags. */
static uint8_t desired_acc(controller_t *c, const ctl_setpoint_t *sp, const ctl_estimate_t *est, float dt,
                           float a[3])
{
    const ctl_params_t *p = &c->p;
    uint8_t flags = 0;
    int i;
    for (i = 0; i < 3; i++) {
        float ep = sp->pos[i] - est->pos[i];
        float ev = sp->vel[i] - est->vel[i];
        if (dt > 0.0f && dt <= p->dt_max && fabsf(ep) <= p->i_err_max) {
            float v = c->integ[i] + ep * dt;
            if (v > p->i_max[i] || v < -p->i_max[i]) {
                flags |= CTL_FLAG_INTEGRATOR_LIMITED;
            }
            c->integ[i] = clampf(v, -p->i_max[i], p->i_max[i]);
        }
        a[i] = sp->acc[i] + p->kp[i] * ep + p->kd[i] * ev + p->ki[i] * c->integ[i];
    }
    a[2] += CTL_GRAVITY;

    /* Keep the commanded thrust vector upright: vertical part >= a_z_min, tilt <= max_tilt. */
    if (a[2] < p->a_z_min) {
        a[2] = p->a_z_min;
        flags |= CTL_FLAG_TILT_LIMITED;
    }
    {
        const float h = sqrtf(a[0] * a[0] + a[1] * a[1]);
        const float h_max = a[2] * trig_tanf(p->max_tilt);
        if (h > h_max) {
            a[0] *= h_max / h;
            a[1] *= h_max / h;
            flags |= CTL_FLAG_TILT_LIMITED;
        }
    }
    return flags;
}

/* The attitude error e_R = vee(R_des^T R - R^T R_des) / 2 of the desired attitude: body z along a,
 * heading from yaw. a_z >= a_z_min > 0 keeps z_d away from the horizontal plane, so z_d x x_c never
 * vanishes. */
static void attitude_error(const float R[3][3], const float a[3], float yaw, float er[3])
{
    float zd[3], xc[3], yd[3], xd[3], M[3][3], n;
    int i, j, k;
    n = sqrtf(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    for (i = 0; i < 3; i++) {
        zd[i] = a[i] / n;
    }
    xc[0] = trig_cosf(yaw);
    xc[1] = trig_sinf(yaw);
    xc[2] = 0.0f;
    cross(zd, xc, yd);
    n = sqrtf(yd[0] * yd[0] + yd[1] * yd[1] + yd[2] * yd[2]);
    for (i = 0; i < 3; i++) {
        yd[i] /= n;
    }
    cross(yd, zd, xd);

    /* M = R_des^T R - R^T R_des (skew-symmetric) */
    for (i = 0; i < 3; i++) {
        for (j = 0; j < 3; j++) {
            /* the columns of R_des are xd, yd, zd */
            const float *cdi = i == 0 ? xd : (i == 1 ? yd : zd);
            const float *cdj = j == 0 ? xd : (j == 1 ? yd : zd);
            float rd_t_r = 0.0f, r_t_rd = 0.0f;
            for (k = 0; k < 3; k++) {
                rd_t_r += cdi[k] * R[k][j];
                r_t_rd += R[k][i] * cdj[k];
            }
            M[i][j] = rd_t_r - r_t_rd;
        }
    }
    er[0] = 0.5f * M[2][1];
    er[1] = 0.5f * M[0][2];
    er[2] = 0.5f * M[1][0];
}

int controller_step(controller_t *c, uint64_t t_us, const ctl_setpoint_t *sp, const ctl_estimate_t *est,
                    ctl_output_t *out)
{
    const ctl_params_t *p = &c->p;
    float R[3][3], a[3], er[3];
    float dt = 0.0f, thrust;
    uint8_t flags;
    int i;

    if (c->has_time && t_us < c->t_us) {
        return CTL_ERR_TIME_BACKWARDS;
    }
    if (c->has_time && c->was_flying) {
        dt = (float)(t_us - c->t_us) * 1e-6f;
    }
    c->t_us = t_us;
    c->has_time = 1;

    if (sp->mode != CTL_MODE_POSITION || !estimate_finite(est) || !quat_to_rot(est->quat, R)) {
        motors_off(c, CTL_MODE_OFF, out);
        return CTL_OK;
    }
    flags = desired_acc(c, sp, est, dt, a);

    /* Collective thrust: the desired force projected on the current body z axis. */
    thrust = p->mass * (a[0] * R[0][2] + a[1] * R[1][2] + a[2] * R[2][2]);
    if (thrust < 0.0f || thrust > p->thrust_max) {
        flags |= CTL_FLAG_THRUST_SATURATED;
        thrust = clampf(thrust, 0.0f, p->thrust_max);
    }
    attitude_error((const float (*)[3])R, a, sp->yaw, er);

    out->mode = CTL_MODE_POSITION;
    out->thrust = thrust;
    for (i = 0; i < 3; i++) {
        float r = -p->k_att[i] * er[i];
        if (r > p->rate_max[i] || r < -p->rate_max[i]) {
            flags |= CTL_FLAG_RATE_LIMITED;
            r = clampf(r, -p->rate_max[i], p->rate_max[i]);
        }
        out->rate[i] = r;
    }
    out->flags = flags;
    c->was_flying = 1;
    return CTL_OK;
}
