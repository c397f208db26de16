/* Take-off and touchdown detector of a vehicle that starts on the floor (EST_MODE_IMU_THRUST, or CONFIG
 * floor_imu in any mode): a Crazyflie log starts on the floor, where the TDoA to low anchors reads metres long
 * (NLOS along the floor), so until the vehicle climbs the estimator gates without re-opening (estimator.c).
 * The climb shows in the thrust-axis accelerometer alone: a leaky integral of the vertical specific force
 * minus g (before take-off the logs read 9.7-9.9 m/s^2, during the climb 10.2-10.9 for about a second).
 * The touchdown shows as a shock: after the flight the shared logs read up to 6.8-38 m/s^2 above g (the vehicle
 * meets the floor, its motors stop), in flight never more than 3.0; it puts the vehicle back on the floor until
 * the next climb. harness/twin/takeoff.py is the twin. */
#ifndef UWB_TAKEOFF_H
#define UWB_TAKEOFF_H

#include <stdint.h>

#define TAKEOFF_TAU_S 1.0f     /* leak of the integral: a bias of the accelerometer stays below the threshold */
#define TAKEOFF_CLIMB_V 0.3f   /* m/s of climb, from the accelerometer alone, that counts as take-off */
#define TAKEOFF_MAX_DT_S 0.1f  /* a longer gap between IMU samples integrates nothing */
#define TAKEOFF_TOUCH_ACC 5.0f /* m/s^2 of vertical specific force above g: a touchdown (or a crash) */
/* A range to the floor (a kind with mm_kind_t.floor_below: the ToF ranger) below its row's bound says the
 * vehicle sits on the floor, in any mode and after a landing too; it holds for this long [us] after it. */
#define TAKEOFF_FLOOR_HOLD_US 200000u

typedef struct {
    float climb_v;     /* leaky integral of the vertical specific force minus g [m/s] */
    uint64_t t_us;     /* previous IMU sample */
    uint8_t has_time;
    uint8_t airborne;  /* set once the climb was seen; cleared by a touchdown or with the filter */
    uint8_t floor;     /* the last range to the floor said: on the floor */
    uint64_t t_floor_us; /* when */
} takeoff_t;

void takeoff_reset(takeoff_t *d);

/* One IMU sample at t_us: acc_z the thrust-axis specific force [m/s^2], r22 = R[2][2] of the attitude
 * (how much of the body z axis points up; 1 without an attitude). Returns d->airborne. */
int takeoff_on_imu(takeoff_t *d, uint64_t t_us, float acc_z, float r22);

/* A range to the floor at t_us said the vehicle sits on it (on_floor = 1) or not. */
void takeoff_on_floor_range(takeoff_t *d, uint64_t t_us, int on_floor);

/* On the floor at t_us: the IMU says so (imu_floor: before the climb, after a touchdown), or a range to the
 * floor said so within TAKEOFF_FLOOR_HOLD_US. */
int takeoff_on_floor(const takeoff_t *d, int imu_floor, uint64_t t_us);

#endif
