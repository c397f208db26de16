/* Kinematic gate (ARCHITECTURE.md, pipeline step 3). */
#include "gate_kinematic.h"

#include <math.h>

float gate_kinematic_dt(int64_t dt_us, int have_ref, float dt_min)
{
    const float dt = have_ref ? (float)dt_us * 1e-6f : dt_min;
    /* The floor avoids the paper code's dt = 0 pathology (measurement in the prediction tick). */
    return dt > dt_min ? dt : dt_min;
}

float gate_kinematic_dmax(const float v[3], float dt, float a_max)
{
    const float speed = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    return speed * dt + 0.5f * a_max * dt * dt;
}

int gate_kinematic_pass(float innovation, float d_max, float factor)
{
    /* Written so that a NaN innovation fails the gate. */
    return fabsf(innovation) <= factor * d_max;
}
