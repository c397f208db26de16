/* Per-pair monitor of the network's corrections (nn_monitor.h); harness/twin/nn_monitor.py is the twin. */
#include "nn_monitor.h"

#include <string.h>

void nn_monitor_reset(nn_monitor_t *m)
{
    memset(m->pair, 0, sizeof m->pair);
}

int nn_monitor_enabled(const nn_monitor_t *m, uint8_t a, uint8_t b)
{
    return a < NN_MON_ANCHORS && b < NN_MON_ANCHORS && !m->pair[a][b].off;
}

static float clipped_square(float y, float S)
{
    const float q = y * y, cap = NN_MON_CLIP * S;
    return q < cap ? q : cap; /* NaN -> cap */
}

int nn_monitor_observe(nn_monitor_t *m, uint8_t a, uint8_t b, float y, float bias, float S)
{
    nn_pair_stat_t *p;
    if (a >= NN_MON_ANCHORS || b >= NN_MON_ANCHORS || !(S > 0.0f)) {
        return 0;
    }
    p = &m->pair[a][b];
    if (p->off) {
        return 0;
    }
    if (p->n == 0u) {
        p->ms_corr = clipped_square(y, S);
        p->ms_raw = clipped_square(y + bias, S);
    } else {
        p->ms_corr += NN_MON_ALPHA * (clipped_square(y, S) - p->ms_corr);
        p->ms_raw += NN_MON_ALPHA * (clipped_square(y + bias, S) - p->ms_raw);
    }
    if (p->n < 0xFFFFu) {
        p->n++;
    }
    if (p->n >= NN_MON_MIN_SAMPLES && p->ms_corr > NN_MON_WORSE * p->ms_raw) {
        p->off = 1u;
        m->disabled++;
        return 1;
    }
    return 0;
}
