/* The estimator's anchor table (estimator.h): 16 slots keyed by any 8-bit id, host positions that stay,
 * radio (LPP) positions valid 2 s, and the supervisor's bounding box of the known anchors. */
#include <string.h>

#include "estimator.h"
#include "id_table.h"
#include "time_ms.h"

/* The table has 16 slots: id_table_first compares four ids per step. */
typedef char anchor_table_holds_16[ESTIMATOR_MAX_ANCHORS == 16 ? 1 : -1];

/* The slot holding id, or -1. */
static int anchor_slot(const estimator_t *est, uint8_t id)
{
    int i = id_table_first(est->anchor_id, id);
    if (i < 0 || ((est->anchor_known >> i) & 1u)) {
        return i;
    }
    for (i++; i < (int)ESTIMATOR_MAX_ANCHORS; i++) {   /* an unused slot held it: look further */
        if (((est->anchor_known >> i) & 1u) && est->anchor_id[i] == id) {
            return i;
        }
    }
    return -1;
}

/* The slot for a new id: the first free one, else the radio position received longest ago, or -1. */
static int anchor_new_slot(const estimator_t *est)
{
    int i, best = -1;
    for (i = 0; i < (int)ESTIMATOR_MAX_ANCHORS; i++) {
        if (!((est->anchor_known >> i) & 1u)) {
            return i;
        }
        if (est->anchor_src[i] == EST_ANCHOR_RADIO &&
            (best < 0 || (int32_t)(est->anchor_ms[i] - est->anchor_ms[best]) < 0)) {
            best = i;
        }
    }
    return best;
}

/* 1 if the two positions are the same bit for bit (no libc memcmp in the image for three words) */
static int same_bits(const float a[3], const float b[3])
{
    uint32_t x[3], y[3];
    memcpy(x, a, sizeof x);
    memcpy(y, b, sizeof y);
    return x[0] == y[0] && x[1] == y[1] && x[2] == y[2];
}

static int store_anchor(estimator_t *est, uint8_t id, const float pos[3], uint8_t src, uint32_t ms)
{
    unsigned i, k;
    int slot = anchor_slot(est, id);
    if (slot >= 0 && src == EST_ANCHOR_RADIO && est->anchor_src[slot] == EST_ANCHOR_HOST) {
        return EST_OK; /* positions configured by the host stay */
    }
    if (slot >= 0 && est->anchor_src[slot] == src && same_bits(est->anchors[slot], pos)) {
        est->anchor_ms[slot] = ms;   /* the same position again (every LPP packet): the box stays */
        return EST_OK;
    }
    slot = slot >= 0 ? slot : anchor_new_slot(est);
    if (slot < 0) {
        return EST_ERR_BAD_ANCHOR_ID;
    }
    memcpy(est->anchors[slot], pos, 3 * sizeof pos[0]);
    est->anchor_id[slot] = id;
    est->anchor_src[slot] = src;
    est->anchor_ms[slot] = ms;
    est->anchor_known = (uint16_t)(est->anchor_known | (1u << slot));
    /* the supervisor's box, from every known anchor (an anchor may be moved) */
    memcpy(est->box_min, pos, sizeof est->box_min);
    memcpy(est->box_max, pos, sizeof est->box_max);
    for (i = 0; i < ESTIMATOR_MAX_ANCHORS; i++) {
        for (k = 0; (est->anchor_known >> i) & 1u && k < 3; k++) {
            est->box_min[k] = est->anchors[i][k] < est->box_min[k] ? est->anchors[i][k] : est->box_min[k];
            est->box_max[k] = est->anchors[i][k] > est->box_max[k] ? est->anchors[i][k] : est->box_max[k];
        }
    }
    return EST_OK;
}

int estimator_set_anchor(estimator_t *est, uint8_t id, const float pos[3])
{
    return store_anchor(est, id, pos, EST_ANCHOR_HOST, 0u);
}

int estimator_set_radio_anchor(estimator_t *est, uint8_t id, const float pos[3], uint64_t t_us)
{
    return store_anchor(est, id, pos, EST_ANCHOR_RADIO, uwb_ms_of_us(t_us));
}

int estimator_anchor_slot(const estimator_t *est, uint8_t id, uint64_t t_us)
{
    const int slot = anchor_slot(est, id);
    if (slot < 0 || (est->anchor_src[slot] == EST_ANCHOR_RADIO &&
                     uwb_ms_of_us(t_us) - est->anchor_ms[slot] >= ESTIMATOR_RADIO_POS_VALID_MS)) {
        return -1;
    }
    return slot;
}

const float *estimator_anchor(const estimator_t *est, uint8_t id, uint64_t t_us)
{
    const int slot = estimator_anchor_slot(est, id, t_us);
    return slot < 0 ? NULL : est->anchors[slot];
}
