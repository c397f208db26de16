#include "tdoa_engine.h"

#include <string.h>

void tdoa_engine_init(tdoa_engine_t *e)
{
    memset(e, 0, sizeof *e);
}

static tdoa_anchor_t *find(tdoa_engine_t *e, uint8_t id)
{
    unsigned i;
    for (i = 0; i < TDOA_STORAGE_COUNT; i++) {
        if (e->anchors[i].in_use && e->anchors[i].id == id) {
            return &e->anchors[i];
        }
    }
    return NULL;
}

const tdoa_anchor_t *tdoa_engine_anchor(const tdoa_engine_t *e, uint8_t id)
{
    return find((tdoa_engine_t *)e, id);
}

/* A free slot, else the one updated longest ago (lowest slot index on ties). */
static tdoa_anchor_t *get_or_create(tdoa_engine_t *e, uint8_t id)
{
    tdoa_anchor_t *a = find(e, id);
    unsigned i;
    if (a != NULL) {
        return a;
    }
    for (i = 0; i < TDOA_STORAGE_COUNT; i++) {
        tdoa_anchor_t *c = &e->anchors[i];
        if (!c->in_use) {
            a = c;
            break;
        }
        if (a == NULL || c->rx_t_us < a->rx_t_us) {
            a = c;
        }
    }
    memset(a, 0, sizeof *a);
    a->in_use = 1;
    a->id = id;
    return a;
}

static uint64_t age_us(uint64_t now, uint64_t then)
{
    return now >= then ? now - then : UINT64_MAX;
}

/* The slot for remote id: its own, else a free one, else the oldest (lowest index on ties). */
static tdoa_tof_t *tof_slot(tdoa_anchor_t *a, uint8_t id)
{
    tdoa_tof_t *slot = NULL;
    unsigned k;
    for (k = 0; k < TDOA_TOF_PER_ANCHOR; k++) {
        if (a->tof[k].has_tof && a->tof[k].id == id) {
            return &a->tof[k];
        }
    }
    for (k = 0; k < TDOA_TOF_PER_ANCHOR; k++) {
        tdoa_tof_t *t = &a->tof[k];
        if (!t->has_tof) {
            return t;
        }
        if (slot == NULL || t->t_us < slot->t_us) {
            slot = t;
        }
    }
    return slot;
}

/* Remember the ToFs the packet carries (TDoA3 short entries carry none: earlier ones are used). */
static void store_tofs(tdoa_anchor_t *a, const lps_packet_t *pkt, uint64_t t_us)
{
    unsigned r;
    for (r = 0; r < pkt->n_remote; r++) {
        const lps_remote_t *rm = &pkt->remote[r];
        tdoa_tof_t *slot;
        if (!rm->has_tof) {
            continue;
        }
        slot = tof_slot(a, rm->id);
        slot->id = rm->id;
        slot->tof = rm->tof;
        slot->has_tof = 1;
        slot->t_us = t_us;
    }
}

static const tdoa_tof_t *lookup_tof(const tdoa_anchor_t *a, uint8_t remote)
{
    unsigned k;
    for (k = 0; k < TDOA_TOF_PER_ANCHOR; k++) {
        if (a->tof[k].has_tof && a->tof[k].id == remote) {
            return &a->tof[k];
        }
    }
    return NULL;
}

/* The bucket rule; returns 1 if this sample is reliable. */
static int clock_update(tdoa_anchor_t *a, uint64_t rx_ts, uint32_t tx_ts)
{
    uint32_t drx, dtx;
    double cand, dev;
    if (!a->has_last) {
        return 0;
    }
    drx = (uint32_t)(rx_ts - a->rx_ts);
    dtx = tx_ts - a->tx_ts;
    if (dtx == 0) {
        return 0;
    }
    cand = (double)drx / (double)dtx;
    dev = cand - a->cc;
    if (dev < TDOA_CC_ACCEPTED_NOISE && dev > -TDOA_CC_ACCEPTED_NOISE) {
        a->cc = TDOA_CC_FILTER * a->cc + (1.0 - TDOA_CC_FILTER) * cand;
        if (a->bucket < TDOA_CC_BUCKET_MAX) {
            a->bucket++;
        }
        return 1;
    }
    if (a->bucket == 0) {
        if (cand > 1.0 - TDOA_CC_MAX_DEVIATION && cand < 1.0 + TDOA_CC_MAX_DEVIATION) {
            a->cc = cand;
        }
    } else {
        a->bucket--;
    }
    return 0;
}

/* Is remote r of the packet usable as reference? 0: yes, else the drop reason it would give. */
static int candidate(tdoa_engine_t *e, const tdoa_anchor_t *an, const lps_remote_t *r, uint64_t t_us,
                     const tdoa_anchor_t **ar_out, const tdoa_tof_t **tof_out)
{
    const tdoa_anchor_t *ar = find(e, r->id);
    const tdoa_tof_t *tof = lookup_tof(an, r->id);
    if (ar == NULL || !ar->has_last || ar->seq != r->seq || tof == NULL) {
        return TDOA_DROP_NO_REFERENCE;
    }
    if (age_us(t_us, ar->rx_t_us) > TDOA_REMOTE_VALID_US || age_us(t_us, tof->t_us) > TDOA_TOF_VALID_US) {
        return TDOA_DROP_EXPIRED;
    }
    *ar_out = ar;
    *tof_out = tof;
    return 0;
}

/* The candidate the tag heard most recently (first in packet order on ties), TDoA2 and TDoA3 alike.
 * The engine's difference multiplies the clock-correction error by the age of the reference, so the
 * youngest reference keeps that part small: ~2.5 ms with TDoA3's random schedule, where the reference's
 * rotating start picked references ~20 ms old (1.3 mm RMS from clock correction alone against 0.2 mm).
 * The schedule is random, so the pairs still vary. */
static int match(tdoa_engine_t *e, const tdoa_anchor_t *an, const lps_packet_t *pkt, uint64_t t_us,
                 const lps_remote_t **rm, const tdoa_anchor_t **ar, const tdoa_tof_t **tof)
{
    int reason = TDOA_DROP_NO_REFERENCE;
    unsigned k;
    for (k = 0; k < pkt->n_remote; k++) {
        const lps_remote_t *r = &pkt->remote[k];
        const tdoa_anchor_t *c_ar = NULL;
        const tdoa_tof_t *c_tof = NULL;
        int why = candidate(e, an, r, t_us, &c_ar, &c_tof);
        if (why != 0) {
            /* Report "expired" only if nothing better turned up. */
            if (why == TDOA_DROP_EXPIRED) {
                reason = why;
            }
            continue;
        }
        if (*ar == NULL || c_ar->rx_t_us > (*ar)->rx_t_us) {
            *rm = r;
            *ar = c_ar;
            *tof = c_tof;
        }
    }
    return *ar != NULL ? TDOA_MEASUREMENT : reason;
}

int tdoa_engine_process(tdoa_engine_t *e, const lps_packet_t *pkt, uint8_t sender, uint64_t rx_ts,
                        uint64_t t_us, tdoa_meas_t *out)
{
    tdoa_anchor_t *an = get_or_create(e, sender);
    const lps_remote_t *rm = NULL;
    const tdoa_anchor_t *ar = NULL;
    const tdoa_tof_t *tof = NULL;
    int reliable, rc = TDOA_DROP_CLOCK;
    rx_ts &= TDOA_MASK40;
    an->packets++;
    store_tofs(an, pkt, t_us);
    reliable = clock_update(an, rx_ts, pkt->tx_ts);
    if (reliable && an->cc > 0.0) {
        rc = match(e, an, pkt, t_us, &rm, &ar, &tof);
    }
    if (rc == TDOA_MEASUREMENT) {
        /* All differences in 32-bit truncated ticks: rx in the tag clock, the sender's part converted
         * to the tag clock by cc. The ToF includes the antenna delay, which the tag's own difference
         * also contains, so it cancels. */
        const uint32_t drx = (uint32_t)(rx_ts - ar->rx_ts);
        const uint32_t dtx = pkt->tx_ts - rm->rx_ts;
        const double ticks = (double)drx - ((double)tof->tof + (double)dtx) * an->cc;
        out->anchor_a = ar->id;
        out->anchor_b = sender;
        out->diff = ticks * (TDOA_SPEED_OF_LIGHT / TDOA_TS_FREQ);
    }
    an->has_last = 1;
    an->seq = pkt->seq;
    an->rx_ts = rx_ts;
    an->tx_ts = pkt->tx_ts;
    an->rx_t_us = t_us;
    return rc;
}
