/* RADIO and CLOCK_REQ frames: anchor packets through the tag's TDoA engine (docs/radio.md). */
#include <string.h>

#include "fw_internal.h"
#include "platform.h"

static void radio_drop(firmware_t *fw, const uwb_msg_t *in, uint8_t reason)
{
    uwb_msg_t out;
    fw_stats_t *s = &fw->stats;
    /* one counter per drop_reason; NO_POSITION and BAD_ANCHOR share one (STATS) */
    uint32_t *const counter[] = {&s->radio_no_position, &s->radio_no_reference, &s->radio_clock, &s->radio_expired,
                                 &s->radio_malformed, &s->radio_unknown_type};
    (*counter[reason < sizeof counter / sizeof counter[0] ? reason : 0])++;
    memset(&out, 0, sizeof out);
    out.type = UWB_MSG_RADIO_DROP;
    out.u.radio_drop.meas_seq = in->seq;
    out.u.radio_drop.reason = reason;
    out.u.radio_drop.anchor_id = (uint8_t)(in->u.radio.src_addr & 0xFFu);
    fw_send_msg(fw, &out);
}

/* Checks the frame itself: length, 40-bit timestamp, zero padding. */
static int radio_frame_ok(const uwb_radio_t *r)
{
    size_t i = r->length;
    uint32_t any = 0, w;
    if (r->length > sizeof r->payload || (r->rx_ts >> 40) != 0) {
        return 0;
    }
    for (; i % 4u != 0 && i < sizeof r->payload; i++) {
        any |= r->payload[i];
    }
    for (; i + 4u <= sizeof r->payload; i += 4u) {   /* the padding four bytes at a time */
        memcpy(&w, &r->payload[i], sizeof w);
        any |= w;
    }
    return any == 0;
}

/* The drop reason of a measurement the engine formed whose positions are not both valid now (0: valid). */
static uint8_t position_check(const firmware_t *fw, const tdoa_meas_t *m, uint64_t t_us)
{
    if (estimator_anchor(&fw->est, m->anchor_a, t_us) == NULL || estimator_anchor(&fw->est, m->anchor_b, t_us) == NULL) {
        return UWB_DROP_REASON_NO_POSITION;
    }
    return 0;
}

/* One anchor packet: parse, TDoA engine, then (if it formed a measurement whose anchors' positions are
 * known) the same pipeline as a TDOA frame. The packet's LPP position is stored after the engine, as a
 * Crazyflie's tag does (it serves the next measurements). Answered by RESULT, RADIO_DROP or ERROR. */
void fw_on_radio(firmware_t *fw, const uwb_msg_t *in)
{
    const uwb_radio_t *r = &in->u.radio;
    const uint8_t sender = (uint8_t)(r->src_addr & 0xFFu);
    lps_packet_t pkt;
    tdoa_meas_t meas;
    estimator_result_t er;
    uint32_t t0, t1;
    int rc;
    t0 = platform_cost_now();
    fw->stats.radio_packets++;
    if (!radio_frame_ok(r)) {
        radio_drop(fw, in, UWB_DROP_REASON_MALFORMED);
        return;
    }
    rc = lps_parse(r->payload, r->length, sender, &pkt);
    if (rc != LPS_OK) {
        radio_drop(fw, in, rc == LPS_ERR_UNKNOWN_TYPE ? UWB_DROP_REASON_UNKNOWN_TYPE : UWB_DROP_REASON_MALFORMED);
        return;
    }
    rc = tdoa_engine_process(&fw->tdoa, &pkt, sender, r->rx_ts, r->t_us, fw->est.cfg.tdoa_match, &meas);
    if (rc == TDOA_MEASUREMENT) {
        rc = position_check(fw, &meas, r->t_us);
    }
    if (pkt.has_pos) {
        (void)estimator_set_radio_anchor(&fw->est, sender, pkt.pos, r->t_us);   /* full table: NO_POSITION */
    }
    if (rc != TDOA_MEASUREMENT) {
        radio_drop(fw, in, (uint8_t)rc);
        return;
    }
    fw->stats.radio_meas++;
    memset(&er, 0, sizeof er);
    rc = estimator_on_tdoa(&fw->est, r->t_us, meas.anchor_a, meas.anchor_b, tdoa_metres_f(meas.ticks), &er);
    t1 = platform_cost_now();
    if (rc != EST_OK) {
        fw_refuse_measurement(fw, in, rc, (uint32_t)meas.anchor_a | ((uint32_t)meas.anchor_b << 8));
        return;
    }
    fw_send_result(fw, in, UWB_MEAS_KIND_TDOA, r->t_us, &er, t1 - t0);
}

void fw_on_clock_req(firmware_t *fw, const uwb_msg_t *in)
{
    const tdoa_anchor_t *a = tdoa_engine_anchor(&fw->tdoa, in->u.clock_req.anchor_id);
    uwb_msg_t out;
    memset(&out, 0, sizeof out);
    out.type = UWB_MSG_CLOCK;
    out.u.clock.anchor_id = in->u.clock_req.anchor_id;
    if (a != NULL) {
        out.u.clock.known = 1;
        out.u.clock.bucket = a->bucket;
        out.u.clock.skew_ppm = tdoa_skew_ppm(a);
        out.u.clock.packets = a->packets;
    }
    fw_send_msg(fw, &out);
}
