/* Robust (M-estimation) scalar update weight: robust_update.h. harness/twin/gates.py is the twin.
 * Unlike the Crazyflie's robust TDoA/TWR update (Geman-McClure weights on measurement and state, two
 * iterations, relinearised), only the measurement is weighted and H stays at the prior: for one scalar
 * measurement this is the part that matters, and it costs a few flops instead of a Cholesky. */
#include "robust_update.h"

#include <math.h>

float robust_r_var(float y, float hph, float r_var)
{
    const float sigma_c = ROBUST_CAUCHY_C * sqrtf(r_var);
    float w = 1.0f;
    int k;
    for (k = 0; k < ROBUST_ITERATIONS; k++) {
        const float rw = r_var / w;
        const float u = (y * rw / (hph + rw)) / sigma_c;
        w = 1.0f / (1.0f + u * u);
        if (!(w >= ROBUST_W_MIN)) { /* also NaN */
            w = ROBUST_W_MIN;
        }
    }
    return r_var / w;
}
