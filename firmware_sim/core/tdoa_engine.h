/* The tag's TDoA engine: turns anchor packets (lps_packets.h) received with the tag's 40-bit DW1000
 * timestamps into TDoA measurements d(tag, An) - d(tag, Ar), An = the sender, Ar = a reference anchor.
 * Behaviour as documented in ../shared/reference/crazyflie-estimator-and-lps.md 4.6: per-anchor clock
 * correction with the bucket rule, reference matching by seq (the youngest candidate, TDoA2 and TDoA3:
 * the reference's TDoA3 tag rotates its start instead, see tdoa_engine.c), 32-bit truncated differences,
 * 40-bit wrap. Bounded storage, no allocation.
 * harness/twin/tdoa_engine.py is the numpy twin. */
#ifndef UWB_TDOA_ENGINE_H
#define UWB_TDOA_ENGINE_H

#include <stdint.h>

#include "lps_packets.h"

#define TDOA_STORAGE_COUNT 16u
#define TDOA_TOF_PER_ANCHOR 8u
#define TDOA_TS_FREQ 63.8976e9            /* DW1000 ticks per second */
#define TDOA_SPEED_OF_LIGHT 299792458.0
#define TDOA_CC_ACCEPTED_NOISE 0.03e-6    /* candidate within this of the estimate: reliable sample */
#define TDOA_CC_MAX_DEVIATION 20e-6       /* a fresh estimate must be within this of 1 */
#define TDOA_CC_FILTER 0.1                /* weight of the old estimate */
#define TDOA_CC_BUCKET_MAX 4u
/* The tag's own reception of a reference anchor must be younger than this: 32-bit differences wrap
 * every 67.2 ms, and LPS anchors transmit at >= 20 Hz. [us] */
#define TDOA_REMOTE_VALID_US 60000u
#define TDOA_TOF_VALID_US 2000000u        /* remote ToFs from earlier packets [us] */
#define TDOA_MASK40 0xFFFFFFFFFFull

/* Outcome of one packet (values = protocol enum drop_reason; TDOA_MEASUREMENT = a measurement). */
enum {
    TDOA_MEASUREMENT = 0,
    TDOA_DROP_NO_REFERENCE = 1,
    TDOA_DROP_CLOCK = 2,
    TDOA_DROP_EXPIRED = 3,
    TDOA_DROP_MALFORMED = 4,
    TDOA_DROP_UNKNOWN_TYPE = 5
};

typedef struct {
    uint8_t id, has_tof;
    uint16_t tof;
    uint64_t t_us;
} tdoa_tof_t;

typedef struct {
    uint8_t in_use, id;
    uint8_t has_last, seq;        /* the last packet the tag received from this anchor */
    uint64_t rx_ts;               /* its tag RX time (40 bits) */
    uint32_t tx_ts;               /* its anchor TX time (32 bits) */
    uint64_t rx_t_us;             /* and when (tag system time) */
    double cc;                    /* clock correction: d(tag clock) / d(anchor clock); 0 = unknown */
    uint8_t bucket;
    uint32_t packets;
    tdoa_tof_t tof[TDOA_TOF_PER_ANCHOR];   /* ToFs remote -> this anchor, this anchor's clock */
} tdoa_anchor_t;

typedef struct {
    tdoa_anchor_t anchors[TDOA_STORAGE_COUNT];
} tdoa_engine_t;

typedef struct {
    uint8_t anchor_a, anchor_b;   /* A = reference Ar, B = sender An */
    double diff;                  /* d(tag, B) - d(tag, A) [m] */
} tdoa_meas_t;

void tdoa_engine_init(tdoa_engine_t *e);

/* One received packet. rx_ts: tag RX time (40 bits, higher bits ignored), t_us: tag system time.
 * Returns TDOA_MEASUREMENT (*out filled) or a TDOA_DROP_* reason; the anchor state is updated either
 * way (a parsed packet always feeds the clock correction and the stored ToFs). */
int tdoa_engine_process(tdoa_engine_t *e, const lps_packet_t *pkt, uint8_t sender, uint64_t rx_ts,
                        uint64_t t_us, tdoa_meas_t *out);

/* The stored context of an anchor, or NULL. */
const tdoa_anchor_t *tdoa_engine_anchor(const tdoa_engine_t *e, uint8_t id);

#endif
