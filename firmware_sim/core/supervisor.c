/* The estimator's supervisor (ARCHITECTURE.md "Supervisor"; twin: harness/twin/supervisor.py). */
#include "supervisor.h"

#include <math.h>
#include <string.h>

/* Beyond this |position| [m] the state counts as diverged even without anchors: far outside any UWB
 * network, and float32 resolution there (~1 cm) is already useless. */
#define EST_MAX_ABS_POSITION 1e5f

/* Signed t1 - t0 in microseconds without relying on unsigned -> signed wrap-around. */
static int64_t diff_us(uint64_t t1, uint64_t t0)
{
    return t1 >= t0 ? (int64_t)(t1 - t0) : -(int64_t)(t0 - t1);
}

/* No UWB measurement for this long [us] is a measurement gap: at the rates of every supported setup
 * (10-400 Hz) a second without one is an outage (a drone on the ground, out of range), not noise. */
#define EST_GAP_US 1000000

/* 1 if no UWB measurement has arrived for EST_GAP_US up to the state's time (or none ever). */
static int measurement_gap(const estimator_t *est)
{
    return !est->has_uwb_time || (est->ekf.has_time && diff_us(est->ekf.t_us, est->t_uwb_us) >= EST_GAP_US);
}

/* The covariance bounds [m^2] of the supervisor: sup_max_var, never below the initial variance. */
static void variance_bounds(const estimator_config_t *cfg, float *var_xy, float *var_z)
{
    *var_xy = cfg->init_std_xy * cfg->init_std_xy;
    *var_z = cfg->init_std_z * cfg->init_std_z;
    *var_xy = *var_xy > cfg->sup_max_var ? *var_xy : cfg->sup_max_var;
    *var_z = *var_z > cfg->sup_max_var ? *var_z : cfg->sup_max_var;
}

/* The supervisor's verdict on the current state: 0 if sane, else the EST_FLAG_* reason. The
 * covariance bound is never below the initial variance (a huge init std is valid). It counts as a
 * divergence only while measurements arrive: without any, the prediction grows P by construction,
 * and a variance above the bound then means "no fix for a while" (EST_FLAG_GAP_RESTART), not a filter
 * that lost track of what it measures. */
static uint8_t supervisor_reason(const estimator_t *est)
{
    const ekf_t *ekf = &est->ekf;
    const estimator_config_t *cfg = &est->cfg;
    const float *p = &ekf->x[EKF_X], *v = &ekf->x[EKF_PX];
    float var_xy, var_z;
    unsigned k;
    if (!ekf_state_finite(ekf)) { /* P's variances: finite after every clamp */
        return EST_FLAG_NON_FINITE;
    }
    for (k = 0; k < 3; k++) {
        if (fabsf(p[k]) > EST_MAX_ABS_POSITION ||
            (est->anchor_known && (p[k] < est->box_min[k] - cfg->sup_margin ||
                                   p[k] > est->box_max[k] + cfg->sup_margin))) {
            return EST_FLAG_OUT_OF_BOX;
        }
    }
    /* body-frame velocity: its norm is the speed whatever the frame */
    if (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > cfg->sup_max_speed * cfg->sup_max_speed) {
        return EST_FLAG_SPEED;
    }
    variance_bounds(cfg, &var_xy, &var_z);
    if (ekf->P[EKF_X][EKF_X] > var_xy || ekf->P[EKF_Y][EKF_Y] > var_xy || ekf->P[EKF_Z][EKF_Z] > var_z) {
        return measurement_gap(est) ? EST_FLAG_GAP_RESTART : EST_FLAG_COVARIANCE;
    }
    return 0;
}

/* Supervisor (as the Crazyflie's kalman_supervisor): a state that is not finite, outside the anchors'
 * box, too fast or too uncertain restarts the filter at the last position that passed, with the
 * initial covariance and zero velocity, keeping the time reference so the filter continues. After a
 * measurement gap the restart (the last fix at rest beats a position extrapolated for seconds) is
 * reported as GAP_RESTART and not counted as a divergence; its position variance is half the bound, not
 * the initial one: the tag may have moved metres meanwhile, and a confident restart would let the
 * chi-square gate refuse the ranges that show it (a circle flown through an 8 s gap: RMSE 1.96 m with
 * the initial 1 m std, 0.11 m with this); half leaves the predictions headroom under the bound until
 * the measurements bring it down. */
void estimator_supervise(estimator_t *est)
{
    ekf_t *ekf = &est->ekf;
    uint64_t t_us;
    uint8_t has_time;
    const uint8_t reason = supervisor_reason(est);
    if (reason == 0) {
        memcpy(est->last_good_pos, &ekf->x[EKF_X], sizeof est->last_good_pos);
        return;
    }
    t_us = ekf->t_us;
    has_time = ekf->has_time;
    if (reason == EST_FLAG_GAP_RESTART) {
        float var_xy, var_z;
        variance_bounds(&est->cfg, &var_xy, &var_z);
        ekf_init(ekf, est->last_good_pos, sqrtf(0.5f * var_xy), sqrtf(0.5f * var_z));
    } else {
        ekf_init(ekf, est->last_good_pos, est->cfg.init_std_xy, est->cfg.init_std_z);
    }
    ekf->t_us = t_us;
    ekf->has_time = has_time;
    if (reason == EST_FLAG_GAP_RESTART) {
        est->gap_restarts++;
        est->flags = (uint8_t)(est->flags | EST_FLAG_GAP_RESTART);
        return;
    }
    est->divergences++;
    est->flags = (uint8_t)(est->flags | EST_FLAG_DIVERGED | reason);
}
