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

/* Bytes after the remote entries: an LPP short packet ANCHOR_POSITION (at least 14 bytes, finite
 * coordinates within LPS_MAX_COORD) sets the position; anything else is ignored, as the Crazyflie's tag
 * ignores LPP data it does not use. */
static void parse_lpp(const uint8_t *p, size_t n, lps_packet_t *out)
{
    int k;
    if (n < 14 || p[0] != LPS_LPP_SHORT || p[1] != LPS_LPP_POSITION) {
        return;
    }
    for (k = 0; k < 3; k++) {
        out->pos[k] = rd_f32(p + 2 + 4 * k);
        /* v != v: NaN; the bound also refuses infinities (has_pos stays 0) */
        if (out->pos[k] != out->pos[k] || out->pos[k] > LPS_MAX_COORD || out->pos[k] < -LPS_MAX_COORD) {
            return;
        }
    }
    out->has_pos = 1;
}

/* TDoA2: the sender's slot is its own TX, the other seven its remotes (a zero stamp or distance:
 * not heard / not ranged, the engine skips it). */
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
        if (i == sender) {
            continue;
        }
        r = &out->remote[out->n_remote++];
        r->id = (uint8_t)i;
        r->seq = (uint8_t)(p[1 + i] & LPS_SEQ_MASK);
        r->rx_ts = rd_u32(p + 9 + 4 * i);
        r->tof = rd_u16(p + 41 + 2 * i);
    }
    parse_lpp(p + LPS_TDOA2_SIZE, n - LPS_TDOA2_SIZE, out);
    return LPS_OK;
}

/* TDoA3: remoteCount entries of 6 bytes, 8 with a distance (seq bit 7). The entries that fit are used;
 * a truncated one ends the list (and there is no LPP after it). */
static int parse_tdoa3(const uint8_t *p, size_t n, uint8_t sender, lps_packet_t *out)
{
    size_t off = LPS_TDOA3_HEADER;
    unsigned i;
    if (n < LPS_TDOA3_HEADER) {
        return LPS_ERR_MALFORMED;
    }
    out->seq = (uint8_t)(p[1] & LPS_SEQ_MASK);
    out->tx_ts = rd_u32(p + 2);
    for (i = 0; i < p[6]; i++) {
        size_t need;
        if (n - off < 6u) {
            return LPS_OK;
        }
        need = (p[off + 1] & 0x80u) ? 8u : 6u;
        if (n - off < need) {
            return LPS_OK;
        }
        if (p[off] != sender && out->n_remote < LPS_MAX_REMOTE) {
            lps_remote_t *r = &out->remote[out->n_remote++];
            r->id = p[off];
            r->seq = (uint8_t)(p[off + 1] & LPS_SEQ_MASK);
            r->rx_ts = rd_u32(p + off + 2);
            r->tof = need == 8u ? rd_u16(p + off + 6) : 0u;
        }
        off += need;
    }
    parse_lpp(p + off, n - off, out);
    return LPS_OK;
}

int lps_parse(const uint8_t *payload, size_t n, uint8_t sender, lps_packet_t *out)
{
    /* everything but the remote entries, which are written up to n_remote */
    out->type = 0;
    out->seq = 0;
    out->tx_ts = 0;
    out->n_remote = 0;
    out->has_pos = 0;
    memset(out->pos, 0, sizeof out->pos);
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
