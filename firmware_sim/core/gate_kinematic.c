/* Kinematic gate (ARCHITECTURE.md, pipeline step 3). */
#include "gate_kinematic.h"

#include <math.h>
#include <string.h>

#include "time_ms.h"

/* Signed t1 - t0 in microseconds without relying on unsigned -> signed wrap-around. */
static int64_t diff_us(uint64_t t1, uint64_t t0)
{
    return t1 >= t0 ? (int64_t)(t1 - t0) : -(int64_t)(t0 - t1);
}

void gate_kinematic_reset(gate_kinematic_t *g)
{
    memset(g, 0, sizeof *g);
}

/* How long the links of anchor id had been rejected up to its previous measurement (0 if that one
 * was fused, or before the first fusion). */
static int64_t anchor_rejected_us(const gate_kinematic_t *g, uint8_t id)
{
    const uint64_t seen = g->t_anchor_seen_us[id], fused = g->t_anchor_fused_us[id];
    return (g->has_fused && seen > fused) ? diff_us(seen, fused) : 0;
}

float gate_kinematic_window(gate_kinematic_t *g, uint64_t t_us, uint8_t id_a, uint8_t id_b, uint64_t t_ref,
                            int have_ref, float dt_min, int widen)
{
    int64_t since_us, rej_a = 0, rej_b = 0;
    if (id_a < GATE_KIN_LINKS && id_b < GATE_KIN_LINKS) {
        rej_a = anchor_rejected_us(g, id_a);
        rej_b = anchor_rejected_us(g, id_b);
        g->t_anchor_seen_us[id_a] = t_us;
        g->t_anchor_seen_us[id_b] = t_us;
    }
    /* dt also counts from the last fused UWB measurement: while measurements are being rejected (an
     * outage, a run of outliers) the bound widens, so the filter cannot lock itself out after drifting
     * more than d_max away. At the nominal rate both references are a few ms old. */
    since_us = diff_us(t_us, t_ref);
    if (widen && have_ref && g->has_fused && diff_us(t_us, g->t_fused_us) > since_us) {
        since_us = diff_us(t_us, g->t_fused_us);
    }
    /* It also widens by the time this link's anchors have been rejected while others were fused: with
     * the estimate off along their direction they alone disagree, and the filter-wide reference above,
     * kept fresh by the others, would hold them out for hundreds of seconds (the hour-long flight). An
     * isolated outlier (the anchor's previous measurement fused) meets the nominal bound. */
    g->rejected_us = !widen ? 0 : (rej_a > rej_b ? rej_a : rej_b);
    if (have_ref) {
        since_us += g->rejected_us;
    }
    return gate_kinematic_dt(since_us, have_ref, dt_min);
}

void gate_kinematic_fused(gate_kinematic_t *g, uint64_t t_us, uint8_t id_a, uint8_t id_b)
{
    unsigned i;
    if (id_a == GATE_KIN_SENSOR) {
        g->t_anchor_fused_us[GATE_KIN_SENSOR] = t_us;
        return;
    }
    if (!g->has_fused) {
        /* The first fusion starts every link's clock: one rejected from then on accrues time. */
        for (i = 0; i < GATE_KIN_LINKS; i++) {
            g->t_anchor_fused_us[i] = t_us;
        }
        g->has_fused = 1;
    }
    g->t_fused_us = t_us;
    if (id_a < GATE_KIN_ANCHORS && id_b < GATE_KIN_ANCHORS) {
        g->t_anchor_fused_us[id_a] = t_us;
        g->t_anchor_fused_us[id_b] = t_us;
    }
}

float gate_kinematic_dt(int64_t dt_us, int have_ref, float dt_min)
{
    const float dt = have_ref ? uwb_i64_to_float(dt_us) * 1e-6f : dt_min;
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
