/* Downward time-of-flight range to the floor (ARCHITECTURE.md, pipeline step 1) and its row of the kinds
 * table. A flow deck's ranger at s = p + R t (t = CONFIG tof_x/y/z, body frame, from the point the state
 * estimates) measures along the body's -z axis to the floor z = 0. That ray meets the floor after
 * h = s_z / R22, R22 = cos(tilt) (the world z component of the body z axis), so
 *     h = (p_z + R[2][0] t_x + R[2][1] t_y + R[2][2] t_z) / R22,   H = [0, 0, 1 / R22].
 * The model holds only while the vehicle is not tipped far (R22 > MM_TOF_MIN_COS) and the range is one
 * the sensor reports (0 <= z < MM_TOF_MAX_RANGE: a ranger sitting on the floor reads 0, and the Crazyflie fuses
 * every reading below its 5 m outlier limit); otherwise REJECTED_GEOMETRY. Its std grows with the range
 * as the Crazyflie's VL53L1x model: std_tof at short range, x 80 between 2.5 m and 4 m. A reading below
 * MM_TOF_FLOOR_BELOW tells the pipeline the vehicle sits on the floor (takeoff.h). It names no anchor:
 * the pipeline keeps its gate state in the sensor's own link (gate_kinematic.h GATE_KIN_SENSOR). */
#include <math.h>

#include "mm_kinds.h"
#include "trig.h"

#define MM_TOF_MIN_COS 0.1f   /* tilt below ~84 deg: beyond it h -> infinity */
#define MM_TOF_MAX_RANGE 5.0f /* [m] the ranger's outlier limit (a VL53L1x reads up to 4 m) */
#define MM_TOF_STD_AT 2.5f    /* [m] the std model: std_tof (1 + exp(k (z - 2.5))), */
#define MM_TOF_STD_K 2.9213f  /* k = ln(80) / 1.5: the std 80 times larger at 4 m than at 2.5 m */
/* [m] a reading below this: the vehicle sits on the floor (the shared logs: 0-26 mm there, >= 0.4 m in flight) */
#define MM_TOF_FLOOR_BELOW 0.1f

static int model(const mm_input_t *in, float *h, float H[3])
{
    const float c = in->R[2][2];
    const float s_z = in->p[2] + in->R[2][0] * in->cfg->tof_x + in->R[2][1] * in->cfg->tof_y + c * in->cfg->tof_z;
    *h = 0.0f;
    H[0] = H[1] = H[2] = 0.0f;
    /* negated comparisons: a NaN attitude, position or range is refused too */
    if (!(c > MM_TOF_MIN_COS) || !(in->z >= 0.0f && in->z < MM_TOF_MAX_RANGE) || !isfinite(s_z)) {
        return MM_DEGENERATE;
    }
    *h = s_z / c;
    H[2] = 1.0f / c;
    return MM_OK;
}

static float std_of(const mm_input_t *in)
{
    return in->cfg->std_tof * (1.0f + trig_expf(MM_TOF_STD_K * (in->z - MM_TOF_STD_AT)));
}

const mm_kind_t mm_kind_tof = {MM_KIND_TOF, 0, model, offsetof(estimator_config_t, std_tof),
                               offsetof(estimator_config_t, chi2_twr), offsetof(estimator_config_t, a_max_twr),
                               1.0f, MM_NO_NET, std_of, MM_TOF_FLOOR_BELOW};
