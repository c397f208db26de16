/* TWR measurement model (ARCHITECTURE.md, pipeline step 1) and the TWR row of the kinds table. */
#include "mm_twr.h"

#include <math.h>

#include "bias_nn.h"

int mm_twr(const float p[3], const float anchor[3], float *h, float H[3])
{
    const float dx = p[0] - anchor[0], dy = p[1] - anchor[1], dz = p[2] - anchor[2];
    const float d = sqrtf(dx * dx + dy * dy + dz * dz);
    /* `!(d >= min)` also catches NaN, so a broken state never yields a usable H; an overflowing
     * distance (absurd but finite coordinates) would give h = inf and H = NaN. */
    if (!(d >= MM_MIN_DISTANCE) || !isfinite(d)) {
        *h = 0.0f;
        H[0] = H[1] = H[2] = 0.0f;
        return MM_DEGENERATE;
    }
    *h = d;
    H[0] = dx / d;
    H[1] = dy / d;
    H[2] = dz / d;
    return MM_OK;
}

static int model(const mm_input_t *in, float *h, float H[3])
{
    return mm_twr(in->p, in->a, h, H);
}

const mm_kind_t mm_kind_twr = {MM_KIND_TWR, 1, model, offsetof(estimator_config_t, std_twr),
                               offsetof(estimator_config_t, chi2_twr), offsetof(estimator_config_t, a_max_twr),
                               1.0f, offsetof(bias_model_t, twr), NULL, 0.0f};
