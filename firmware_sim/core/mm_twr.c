/* TWR measurement model (ARCHITECTURE.md, pipeline step 1). */
#include "mm_twr.h"

#include <math.h>

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
