/* The IMU path of the estimator (estimator.h): the floor rule's take-off and touchdown (takeoff.h) and the
 * EKF's prediction from each sample. */
#include "estimator.h"

#include "platform.h"
#include "supervisor.h"

int estimator_on_imu(estimator_t *est, uint64_t t_us, const float acc[3], const float gyro[3])
{
    uint32_t c0;
    int due;
    ekf_noise_t noise;
    float a[3];
    if (est->has_imu_time && t_us < est->t_imu_us) {
        return EST_ERR_TIME_BACKWARDS;
    }
    est->t_imu_us = t_us;
    est->has_imu_time = 1;
    if (estimator_floor_from_imu(&est->cfg)) { /* UWB-only: R is the identity, the vehicle taken as level */
        const int flying = est->takeoff.airborne;
        if (!takeoff_on_imu(&est->takeoff, t_us, acc[2], est->ekf.R[2][2]) && flying) {
            ekf_hold_at_rest(&est->ekf); /* a touchdown: the vehicle stopped */
        }
    }
    if (est->cfg.mode == EST_MODE_UWB_ONLY) {
        est->imu_ignored++;
        return EST_OK;
    }
    noise.acc_xy = est->cfg.proc_acc_xy;
    noise.acc_z = est->cfg.proc_acc_z;
    a[0] = acc[0];
    a[1] = acc[1];
    a[2] = acc[2];
    if (est->cfg.mode == EST_MODE_IMU_THRUST) {
        /* A quadrotor's rotors push along body z only: its horizontal specific force is drag, small, while
         * what the accelerometer reads there in flight is mostly vibration (a Crazyflie's: -2 m/s^2 mean,
         * 2 m/s^2 std, docs/real-flights.md). The Crazyflie's estimator uses the same model in flight. */
        a[0] = 0.0f;
        a[1] = 0.0f;
    }
    due = ekf_imu_due(&est->ekf, t_us); /* the other samples are only summed: not timed */
    c0 = due ? platform_cost_now() : 0u;
    (void)ekf_imu_sample(&est->ekf, &noise, t_us, a, gyro);
    if (due) {
        est->predictions++;
        estimator_supervise(est);
        est->cost_predict += platform_cost_now() - c0;
    }
    return EST_OK;
}
