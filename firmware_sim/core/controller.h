/* Position controller for the closed loop (Mellinger-style geometric controller, as in the paper).
 *
 * Each control step reads the EKF estimate (position, world velocity, attitude) and the latest
 * setpoint, and returns a collective thrust [N] and body-rate commands [rad/s]:
 *   a_des  = a_ff + Kp e_p + Kd e_v + Ki int(e_p) + g e3          (world, m/s^2)
 *            limited to a_z >= a_z_min and a tilt of at most max_tilt from vertical
 *   thrust = m a_des . b3                                        (b3: estimated body z axis)
 *   R_des  = [x_d y_d z_d], z_d = a_des/|a_des|, heading from the commanded yaw
 *   e_R    = vee(R_des^T R - R^T R_des) / 2,   rates = -K_R e_R  (clipped)
 * The body-rate loop (on a Crazyflie: 500 Hz on the gyro) belongs to the vehicle side.
 * OS-free C99, no allocation, state passed by pointer. */
#ifndef UWB_CONTROLLER_H
#define UWB_CONTROLLER_H

#include <stdint.h>

/* Return codes (CTL_ERR_TIME_BACKWARDS equals the protocol's error_code TIME_BACKWARDS). */
enum { CTL_OK = 0, CTL_ERR_TIME_BACKWARDS = 5 };

/* Modes (= protocol enum control_mode). */
enum { CTL_MODE_OFF = 0, CTL_MODE_POSITION = 1 };

/* Output flags (= protocol enum control_flag). */
enum {
    CTL_FLAG_THRUST_SATURATED = 1,
    CTL_FLAG_TILT_LIMITED = 2,
    CTL_FLAG_RATE_LIMITED = 4,
    CTL_FLAG_INTEGRATOR_LIMITED = 8
};

typedef struct {
    float mass;           /* kg, the controller's model of the vehicle */
    float kp[3];          /* position gain per axis [1/s^2] */
    float kd[3];          /* velocity gain [1/s] */
    float ki[3];          /* position-error integral gain [1/s^3] */
    float i_max[3];       /* bound of each integral [m s] */
    float i_err_max;      /* the position error is integrated only while |e| <= this [m]: a large
                           * transient error says nothing about a steady-state one (no wind-up) */
    float k_att[3];       /* attitude error -> body rate [1/s] (roll, pitch, yaw) */
    float rate_max[3];    /* body-rate command bound [rad/s] */
    float max_tilt;       /* bound of the commanded tilt from vertical [rad], in (0, pi/2) */
    float a_z_min;        /* lower bound of the commanded vertical acceleration incl. g [m/s^2], > 0 */
    float thrust_max;     /* collective thrust bound [N] */
    float dt_max;         /* longest step the integrator accepts [s] (a gap is not integrated) */
} ctl_params_t;

typedef struct {
    uint8_t mode;         /* CTL_MODE_* */
    float pos[3], vel[3], acc[3];  /* world frame; vel and acc are feed-forward */
    float yaw;            /* rad */
} ctl_setpoint_t;

typedef struct {
    float pos[3];
    float vel[3];         /* world frame */
    float quat[4];        /* (w, x, y, z), body -> world */
} ctl_estimate_t;

typedef struct {
    uint8_t mode;         /* OFF if the setpoint was OFF or the estimate is unusable */
    uint8_t flags;        /* CTL_FLAG_* */
    float thrust;         /* N, in [0, thrust_max] */
    float rate[3];        /* body-rate command [rad/s] */
} ctl_output_t;

typedef struct {
    ctl_params_t p;
    float integ[3];       /* integral of the position error [m s] */
    uint64_t t_us;        /* time of the previous step */
    uint8_t has_time;
    uint8_t was_flying;   /* previous step was POSITION with a usable estimate */
} controller_t;

/* Defaults tuned for a ~32 g Crazyflie 2.x with a Loco deck (docs/closed-loop.md). */
void controller_default_params(ctl_params_t *p);

/* 1 if every parameter is finite and in range. */
int controller_params_valid(const ctl_params_t *p);

/* Zero integrals, no time reference. p must be valid. */
void controller_init(controller_t *c, const ctl_params_t *p);

/* One control step at t_us. CTL_ERR_TIME_BACKWARDS (nothing changes) if t_us is before the previous
 * step. OFF (or a non-finite estimate) gives zero thrust and rates and resets the integrals. */
int controller_step(controller_t *c, uint64_t t_us, const ctl_setpoint_t *sp, const ctl_estimate_t *est,
                    ctl_output_t *out);

#endif
