/* Take-off detector (takeoff.h). */
#include "takeoff.h"

#include <string.h>

#include "ekf_core.h"
#include "time_ms.h"

void takeoff_reset(takeoff_t *d)
{
    memset(d, 0, sizeof *d);
}

int takeoff_on_imu(takeoff_t *d, uint64_t t_us, float acc_z, float r22)
{
    const float up = r22 * acc_z - EKF_GRAVITY;
    float dt;
    if (up > TAKEOFF_TOUCH_ACC) { /* a touchdown: on the floor again, the next climb counts from here */
        d->climb_v = 0.0f;
        d->airborne = 0;
    } else if (d->has_time && t_us > d->t_us) {
        dt = uwb_u64_to_float(t_us - d->t_us) * 1e-6f;
        if (dt <= TAKEOFF_MAX_DT_S) {
            d->climb_v += dt * up - d->climb_v * (dt / TAKEOFF_TAU_S);
        }
    }
    d->t_us = t_us;
    d->has_time = 1;
    if (d->climb_v > TAKEOFF_CLIMB_V) {
        d->airborne = 1;
    }
    return d->airborne;
}

void takeoff_on_floor_range(takeoff_t *d, uint64_t t_us, int on_floor)
{
    d->floor = (uint8_t)(on_floor != 0);
    d->t_floor_us = t_us;
}

int takeoff_on_floor(const takeoff_t *d, int imu_floor, uint64_t t_us)
{
    if (imu_floor && !d->airborne) {
        return 1;
    }
    return d->floor && t_us >= d->t_floor_us && t_us - d->t_floor_us < TAKEOFF_FLOOR_HOLD_US;
}
