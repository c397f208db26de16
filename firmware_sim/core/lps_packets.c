#include "lps_packets.h"

#include <string.h>

static uint32_t rd_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static uint16_t rd_u16(const uint8_t *p)
{
    return (uint16_t)((unsigned)p[0] | ((unsigned)p[1] << 8));
}

static float rd_f32(const uint8_t *p)
{
    uint32_t u = rd_u32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* LPP short packet at the end of an anchor payload. Only ANCHOR_POSITION is used; other LPP ids are
 * accepted and ignored (an anchor may carry them), an ANCHOR_POSITION of the wrong size or with a
 * non-finite or implausible coordinate is malformed. */
static int parse_lpp(const uint8_t *p, size_t n, lps_packet_t *out)
{
    int k;
    if (n == 0) {
        return LPS_OK;
    }
    if (n < 2 || p[0] != LPS_LPP_SHORT) {
        return LPS_ERR_MALFORMED;
    }
    if (p[1] != LPS_LPP_POSITION) {
        return LPS_OK;
    }
    if (n != 14) {
        return LPS_ERR_MALFORMED;
    }
    for (k = 0; k < 3; k++) {
        float v = rd_f32(p + 2 + 4 * k);
        /* v != v: NaN; the bound also refuses infinities. */
        if (v != v || v > LPS_MAX_COORD || v < -LPS_MAX_COORD) {
            return LPS_ERR_MALFORMED;
        }
        out->pos[k] = v;
    }
    out->has_pos = 1;
    return LPS_OK;
}

static int parse_tdoa2(const uint8_t *p, size_t n, uint8_t sender, lps_packet_t *out)
{
    unsigned i;
    if (n < LPS_TDOA2_SIZE || sender >= LPS_TDOA2_ANCHORS) {
        return LPS_ERR_MALFORMED;
    }
    out->seq = (uint8_t)(p[1 + sender] & LPS_SEQ_MASK);
    out->tx_ts = rd_u32(p + 9 + 4 * sender);
    for (i = 0; i < LPS_TDOA2_ANCHORS; i++) {
        lps_remote_t *r;
        uint32_t ts = rd_u32(p + 9 + 4 * i);
        /* Slot i of the sender is its own TX; a zero timestamp means "not heard". */
        if (i == sender || ts == 0) {
            continue;
        }
        r = &out->remote[out->n_remote++];
        r->id = (uint8_t)i;
        r->seq = (uint8_t)(p[1 + i] & LPS_SEQ_MASK);
        r->rx_ts = ts;
        r->tof = rd_u16(p + 41 + 2 * i);
        r->has_tof = r->tof != 0;
    }
    return parse_lpp(p + LPS_TDOA2_SIZE, n - LPS_TDOA2_SIZE, out);
}

static int parse_tdoa3(const uint8_t *p, size_t n, uint8_t sender, lps_packet_t *out)
{
    size_t off = LPS_TDOA3_HEADER;
    unsigned i, count;
    if (n < LPS_TDOA3_HEADER) {
        return LPS_ERR_MALFORMED;
    }
    out->seq = (uint8_t)(p[1] & LPS_SEQ_MASK);
    out->tx_ts = rd_u32(p + 2);
    count = p[6];
    if (count > LPS_MAX_REMOTE) {
        return LPS_ERR_MALFORMED;
    }
    for (i = 0; i < count; i++) {
        lps_remote_t *r = &out->remote[i];
        size_t need;
        if (n - off < 6) {
            return LPS_ERR_MALFORMED;
        }
        r->id = p[off];
        r->has_tof = (uint8_t)(p[off + 1] >> 7);
        r->seq = (uint8_t)(p[off + 1] & LPS_SEQ_MASK);
        r->rx_ts = rd_u32(p + off + 2);
        need = r->has_tof ? 8u : 6u;
        if (n - off < need || r->id == sender) {
            return LPS_ERR_MALFORMED;
        }
        r->tof = r->has_tof ? rd_u16(p + off + 6) : 0u;
        /* A zero ToF carries no information (the anchor has not ranged yet). */
        r->has_tof = (uint8_t)(r->has_tof && r->tof != 0);
        off += need;
    }
    out->n_remote = (uint8_t)count;
    return parse_lpp(p + off, n - off, out);
}

int lps_parse(const uint8_t *payload, size_t n, uint8_t sender, lps_packet_t *out)
{
    memset(out, 0, sizeof *out);
    if (n == 0) {
        return LPS_ERR_MALFORMED;
    }
    out->type = payload[0];
    if (payload[0] == LPS_TYPE_TDOA2) {
        return parse_tdoa2(payload, n, sender, out);
    }
    if (payload[0] == LPS_TYPE_TDOA3) {
        return parse_tdoa3(payload, n, sender, out);
    }
    return LPS_ERR_UNKNOWN_TYPE;
}
