#include "tdoa_engine.h"

#include <string.h>

#include "id_table.h"
#include "time_ms.h"

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

/* The context of id; a missing one is created (*created = 1) in the first free slot, else in the one
 * whose last packet is the oldest, strictly before now (slot 0 if none is). */
static tdoa_anchor_t *get_or_create(tdoa_engine_t *e, uint8_t id, uint32_t now_ms, int *created)
{
    tdoa_anchor_t *a = find(e, id);
    unsigned i, victim = 0;
    uint32_t oldest = now_ms;
    *created = a == NULL;
    if (a != NULL) {
        return a;
    }
    for (i = 0; i < TDOA_STORAGE_COUNT; i++) {
        if (!e->anchors[i].in_use) {
            victim = i;
            break;
        }
        if (e->anchors[i].last_ms < oldest) {
            oldest = e->anchors[i].last_ms;
            victim = i;
        }
    }
    a = &e->anchors[victim];
    memset(a, 0, sizeof *a);
    a->in_use = 1;
    a->id = id;
    return a;
}

/* The remote and ToF tables have 16 slots: id_table_first compares four ids per step. */
typedef char tdoa_tables_hold_16[(TDOA_REMOTE_COUNT == 16u && TDOA_TOF_COUNT == 16u) ? 1 : -1];

/* Slot for id in a table of 16 (ids, end_ms): the first slot holding id, else the first one that
 * expires earliest. Unused slots hold id 0 and end 0. */
static unsigned slot_for(const uint8_t *ids, const uint32_t *end_ms, uint8_t id)
{
    const int found = id_table_first(ids, id);
    unsigned k, best = 0;
    if (found >= 0) {
        return (unsigned)found;
    }
    for (k = 1; k < 16u; k++) {
        if (end_ms[k] < end_ms[best]) {
            best = k;
        }
    }
    return best;
}

/* Index of id's live entry (the first slot holding id, if it has not expired), or -1. */
static int live(const uint8_t *ids, const uint32_t *end_ms, uint8_t id, uint32_t now_ms)
{
    const int k = id_table_first(ids, id);
    return k >= 0 && end_ms[k] > now_ms ? k : -1;
}

static uint16_t tof_of(const tdoa_anchor_t *a, uint8_t id, uint32_t now_ms)
{
    const int k = live(a->tof.id, a->tof.end_ms, id, now_ms);
    return k < 0 ? 0u : a->tof.tof[k];
}

/* Remember what the packet reports: remote RX data (if the stamp is not 0) and ToFs (if not 0). */
static void store_remotes(tdoa_anchor_t *a, const lps_packet_t *pkt, uint32_t now_ms)
{
    unsigned r;
    for (r = 0; r < pkt->n_remote; r++) {
        const lps_remote_t *rm = &pkt->remote[r];
        if (rm->rx_ts != 0) {
            tdoa_remote_t *d = &a->remote;
            const unsigned k = slot_for(d->id, d->end_ms, rm->id);
            d->id[k] = rm->id;
            d->seq[k] = rm->seq;
            d->rx_ts[k] = rm->rx_ts;
            d->end_ms[k] = now_ms + TDOA_REMOTE_VALID_MS;
        }
        if (rm->tof != 0) {
            tdoa_tofs_t *t = &a->tof;
            const unsigned k = slot_for(t->id, t->end_ms, rm->id);
            t->id[k] = rm->id;
            t->tof[k] = rm->tof;
            t->end_ms[k] = now_ms + TDOA_TOF_VALID_MS;
        }
    }
}

/* The bucket rule on candidate = trunc32(rx - rx_prev) / trunc32(tx - tx_prev), in the integer arithmetic
 * of tdoa_clock.h (the same values as double; a ratio outside [0.5, 2), a zero TX interval included, is
 * never reliable). Needs a previous packet (both its stamps non-zero). Returns 1 if reliable. */
static int clock_update(tdoa_anchor_t *a, uint64_t rx_ts, uint32_t tx_ts)
{
    uint64_t cand;
    if (a->rx_ts == 0 || a->tx_ts == 0) {
        return 0;
    }
    cand = tdoa_clock_ratio((uint32_t)(rx_ts - a->rx_ts), tx_ts - a->tx_ts);
    if (cand != 0 && tdoa_clock_near(cand, a->cc)) {
        a->cc = tdoa_clock_filter(a->cc, cand);
        if (a->bucket < TDOA_CC_BUCKET_MAX) {
            a->bucket++;
        }
        return 1;
    }
    if (a->bucket > 0) {
        a->bucket--;
    } else if (cand > TDOA_CC_LOW_FX && cand < TDOA_CC_HIGH_FX) {
        a->cc = cand;
    }
    return 0;
}

/* The reference among An's live remote records (slot order), searched in a copy of them (a lookup may
 * evict An itself when more than 16 anchors are in view: the reference's tag goes on through its copy).
 * A candidate's anchor must be stored already (looking it up creates it otherwise, as the reference's
 * storage does), the seq An reports must be that of the tag's last packet from it, and An must know a live
 * ToF from it. random: the search starts at an engine-wide 8-bit offset, +1 per search; the first
 * candidate wins. youngest: the candidate whose anchor the tag heard last (whole ms, > 0, strictly later
 * than the earlier ones: ties go to the first); its ToF is checked before the lookup. *rx: the record's
 * rx_Ar_by_An, *tof its ToF. */
static tdoa_anchor_t *find_reference(tdoa_engine_t *e, const tdoa_anchor_t *an, uint32_t now_ms, int youngest,
                                     uint32_t *rx, uint16_t *tof)
{
    uint8_t ids[TDOA_REMOTE_COUNT], seqs[TDOA_REMOTE_COUNT];
    uint32_t rxs[TDOA_REMOTE_COUNT];
    tdoa_anchor_t *best = NULL;
    unsigned n = 0, k, i, start = 0;
    for (k = 0; k < TDOA_REMOTE_COUNT; k++) {
        if (an->remote.end_ms[k] > now_ms) {
            ids[n] = an->remote.id[k];
            seqs[n] = an->remote.seq[k];
            rxs[n++] = an->remote.rx_ts[k];
        }
    }
    if (!youngest) {
        start = ++e->offset;
    }
    for (i = start; i < start + n; i++) {
        const unsigned r = i % n;
        const uint16_t t = tof_of(an, ids[r], now_ms);
        tdoa_anchor_t *ar;
        int created;
        if (youngest && t == 0) {
            continue;
        }
        ar = get_or_create(e, ids[r], now_ms, &created);
        if (created || t == 0 || seqs[r] != ar->seq ||
            (youngest && ar->last_ms <= (best != NULL ? best->last_ms : 0u))) {
            continue;
        }
        best = ar;
        *rx = rxs[r];
        *tof = t;
        if (!youngest) {
            break;
        }
    }
    return best;
}

/* tdoa = trunc32(rx_An - rx_Ar) - (tof + trunc32(tx_An - rx_Ar_by_An)) cc, truncated toward zero. */
static int64_t tdoa_ticks(const tdoa_anchor_t *an, const tdoa_anchor_t *ar, uint32_t rx_ar_by_an, uint64_t rx_ts,
                          uint32_t tx_ts, uint16_t tof)
{
    const uint32_t drx = (uint32_t)(rx_ts - ar->rx_ts);
    const uint32_t dtx = tx_ts - rx_ar_by_an;
    return tdoa_clock_ticks(drx, (uint64_t)tof + dtx, an->cc);
}

double tdoa_metres(int64_t ticks)
{
    return TDOA_SPEED_OF_LIGHT * (double)ticks / TDOA_TS_FREQ;
}

float tdoa_metres_f(int64_t ticks)
{
    return uwb_i64_to_float(ticks) * TDOA_METRES_PER_TICK_F;
}

float tdoa_skew_ppm(const tdoa_anchor_t *a)
{
    /* (cc - 1) 1e6 with cc in units of 2^-53 */
    return a->cc != 0 ? (float)(int64_t)(a->cc - TDOA_CC_ONE) * (1e6f / 9007199254740992.0f) : 0.0f;
}

int tdoa_engine_process(tdoa_engine_t *e, const lps_packet_t *pkt, uint8_t sender, uint64_t rx_ts,
                        uint64_t t_us, int match, tdoa_meas_t *out)
{
    const uint32_t now_ms = uwb_ms_of_us(t_us);
    int created, rc = TDOA_DROP_CLOCK;
    tdoa_anchor_t *an = get_or_create(e, sender, now_ms, &created);
    rx_ts &= TDOA_MASK40;
    an->packets++;
    store_remotes(an, pkt, now_ms);
    if (clock_update(an, rx_ts, pkt->tx_ts) && an->cc != 0) {
        const int youngest = match == TDOA_MATCH_YOUNGEST || (match == TDOA_MATCH_AUTO && pkt->type == LPS_TYPE_TDOA2);
        uint16_t tof = 0;
        uint32_t rx_ar = 0;
        const tdoa_anchor_t *ar = find_reference(e, an, now_ms, youngest, &rx_ar, &tof);
        rc = TDOA_DROP_NO_REFERENCE;
        if (ar != NULL) {
            out->anchor_a = ar->id;
            out->anchor_b = sender;
            out->ticks = tdoa_ticks(an, ar, rx_ar, rx_ts, pkt->tx_ts, tof);
            rc = TDOA_MEASUREMENT;
        }
    }
    an->seq = pkt->seq;
    an->rx_ts = rx_ts;
    an->tx_ts = pkt->tx_ts;
    an->last_ms = now_ms;
    return rc;
}
