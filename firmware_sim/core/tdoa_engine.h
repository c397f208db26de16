/* The tag's TDoA engine: turns anchor packets (lps_packets.h) received with the tag's 40-bit DW1000
 * timestamps into TDoA measurements d(tag, An) - d(tag, Ar), An = the sender, Ar = a reference anchor.
 * It forms what a Crazyflie's tag forms from the same packets (Bitcraze crazyflie-firmware 2026.08,
 * tdoaEngine / tdoaStorage / clockCorrectionEngine, studied for their behaviour; our own code):
 * storage and expiry in whole milliseconds of tag time, per-anchor clock correction with the bucket
 * rule, reference matching "random" (rotating start, the TDoA3 tag's default) or "youngest" (TDoA2),
 * the difference in whole clock ticks truncated toward zero. docs/radio.md lists each rule.
 * Bounded storage, no allocation. harness/twin/tdoa_engine.py is the twin. */
#ifndef UWB_TDOA_ENGINE_H
#define UWB_TDOA_ENGINE_H

#include <stdint.h>

#include "lps_packets.h"
#include "tdoa_clock.h"

#define TDOA_STORAGE_COUNT 16u            /* anchor contexts */
#define TDOA_REMOTE_COUNT 16u             /* remote RX data per anchor */
#define TDOA_TOF_COUNT 16u                /* remote ToFs per anchor */
#define TDOA_REMOTE_VALID_MS 30u          /* remote RX data expires [ms] */
#define TDOA_TOF_VALID_MS 2000u           /* remote ToFs expire [ms] */
#define TDOA_TS_FREQ 63.8976e9            /* DW1000 ticks per second */
#define TDOA_SPEED_OF_LIGHT 299792458.0
#define TDOA_METRES_PER_TICK_F ((float)(TDOA_SPEED_OF_LIGHT / TDOA_TS_FREQ))   /* folded at compile time */
/* clock correction (tdoa_clock.h holds these in its integer units): a candidate within 0.03e-6 of the
 * estimate is a reliable sample, filtered with weight 0.1 on the old estimate; a fresh estimate must be
 * within 20e-6 of 1 */
#define TDOA_CC_ACCEPTED_NOISE 0.03e-6
#define TDOA_CC_MAX_DEVIATION 20e-6
#define TDOA_CC_FILTER 0.1
#define TDOA_CC_BUCKET_MAX 4u
#define TDOA_MASK32 0xFFFFFFFFull
#define TDOA_MASK40 0xFFFFFFFFFFull

/* Reference matching (= protocol enum tdoa_match). AUTO: as a Crazyflie's tag, TDoA2 packets youngest,
 * TDoA3 packets random. */
enum { TDOA_MATCH_AUTO = 0, TDOA_MATCH_RANDOM = 1, TDOA_MATCH_YOUNGEST = 2 };

/* Outcome of one packet (values = protocol enum drop_reason; TDOA_MEASUREMENT = a measurement). */
enum {
    TDOA_MEASUREMENT = 0,
    TDOA_DROP_NO_REFERENCE = 1,
    TDOA_DROP_CLOCK = 2,
    TDOA_DROP_MALFORMED = 4,
    TDOA_DROP_UNKNOWN_TYPE = 5
};

/* Remote data the anchor reported: parallel arrays (no padding). Unused slots: id 0, end 0. */
typedef struct {
    uint8_t id[TDOA_REMOTE_COUNT];
    uint8_t seq[TDOA_REMOTE_COUNT];
    uint32_t rx_ts[TDOA_REMOTE_COUNT];   /* when the anchor received it, anchor clock, 32 bits */
    uint32_t end_ms[TDOA_REMOTE_COUNT];  /* valid while now_ms < end_ms */
} tdoa_remote_t;

typedef struct {
    uint8_t id[TDOA_TOF_COUNT];
    uint16_t tof[TDOA_TOF_COUNT];        /* ToF remote -> this anchor, its clock, antenna delay included */
    uint32_t end_ms[TDOA_TOF_COUNT];
} tdoa_tofs_t;

typedef struct {
    uint8_t in_use, id;
    uint8_t seq;                  /* the last packet the tag received from this anchor: seq, */
    uint8_t bucket;
    uint64_t rx_ts;               /* its tag RX time (40 bits; 0 = none), */
    uint32_t tx_ts;               /* its anchor TX time (32 bits; 0 = none), */
    uint32_t last_ms;             /* and when (tag time, ms) */
    uint32_t packets;
    uint64_t cc;                  /* clock correction d(tag clock) / d(anchor clock) in units of 2^-53
                                     (tdoa_clock.h: exactly the double of the same name); 0 = unknown */
    tdoa_remote_t remote;
    tdoa_tofs_t tof;
} tdoa_anchor_t;

typedef struct {
    tdoa_anchor_t anchors[TDOA_STORAGE_COUNT];
    uint8_t offset;               /* random matching: start of the next search (8 bits, wraps) */
} tdoa_engine_t;

typedef struct {
    uint8_t anchor_a, anchor_b;   /* A = reference Ar, B = sender An */
    int64_t ticks;                /* d(tag, B) - d(tag, A) in whole ticks of the tag clock */
} tdoa_meas_t;

void tdoa_engine_init(tdoa_engine_t *e);

/* One parsed packet. rx_ts: tag RX time (40 bits, higher bits ignored), t_us: tag system time,
 * match: TDOA_MATCH_*. Returns TDOA_MEASUREMENT (*out filled) or a TDOA_DROP_* reason; the anchor
 * state is updated either way (remote data, ToFs, clock correction, the last packet). */
int tdoa_engine_process(tdoa_engine_t *e, const lps_packet_t *pkt, uint8_t sender, uint64_t rx_ts,
                        uint64_t t_us, int match, tdoa_meas_t *out);

/* A difference in metres: c ticks / f in double (tests, tools), and in float for the estimator (one
 * float multiply: within one float ulp of the double rounded to float). */
double tdoa_metres(int64_t ticks);
float tdoa_metres_f(int64_t ticks);

/* The clock skew (cc - 1) 1e6 [ppm] of an anchor's context, 0 if unknown (CLOCK replies). */
float tdoa_skew_ppm(const tdoa_anchor_t *a);

/* The stored context of an anchor, or NULL. */
const tdoa_anchor_t *tdoa_engine_anchor(const tdoa_engine_t *e, uint8_t id);

#endif
