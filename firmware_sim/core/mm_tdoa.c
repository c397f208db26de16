/* TDoA measurement model (ARCHITECTURE.md, pipeline step 1) and the TDoA row of the kinds table. */
#include "mm_tdoa.h"

#include <math.h>

#include "bias_nn.h"

int mm_tdoa(const float p[3], const float anchor_a[3], const float anchor_b[3], float *h, float H[3])
{
    const float ax = p[0] - anchor_a[0], ay = p[1] - anchor_a[1], az = p[2] - anchor_a[2];
    const float bx = p[0] - anchor_b[0], by = p[1] - anchor_b[1], bz = p[2] - anchor_b[2];
    const float abx = anchor_b[0] - anchor_a[0], aby = anchor_b[1] - anchor_a[1],
                abz = anchor_b[2] - anchor_a[2];
    const float da = sqrtf(ax * ax + ay * ay + az * az);
    const float db = sqrtf(bx * bx + by * by + bz * bz);
    const float dab = sqrtf(abx * abx + aby * aby + abz * abz);
    /* Negated comparisons also reject NaN distances; overflowing ones (absurd but finite
     * coordinates) would give h = inf - inf. */
    if (!(da >= MM_MIN_DISTANCE) || !(db >= MM_MIN_DISTANCE) || !(dab >= MM_MIN_DISTANCE) ||
        !isfinite(da) || !isfinite(db) || !isfinite(dab)) {
        *h = 0.0f;
        H[0] = H[1] = H[2] = 0.0f;
        return MM_DEGENERATE;
    }
    *h = db - da;
    H[0] = bx / db - ax / da;
    H[1] = by / db - ay / da;
    H[2] = bz / db - az / da;
    return MM_OK;
}

/* A TDoA's |diff| must be below the distance between its two anchors (a Crazyflie's outlier filter
 * discards the others before its update: physically impossible, most likely a measurement error). */
static int within_baseline(const float *a, const float *b, float diff)
{
    const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return diff * diff < dx * dx + dy * dy + dz * dz;
}

static int model(const mm_input_t *in, float *h, float H[3])
{
    const int rc = mm_tdoa(in->p, in->a, in->b, h, H);
    return rc == MM_OK && !within_baseline(in->a, in->b, in->z) ? MM_OUT_OF_BASELINE : rc;
}

const mm_kind_t mm_kind_tdoa = {MM_KIND_TDOA, 2, model, offsetof(estimator_config_t, std_tdoa),
                                offsetof(estimator_config_t, chi2_tdoa), offsetof(estimator_config_t, a_max_tdoa),
                                2.0f, offsetof(bias_model_t, tdoa), NULL, 0.0f};
