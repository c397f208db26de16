/* The tag's TDoA engine and its packet parser, on hand-built packet sequences: exact differences with
 * ideal clocks across the 2^32 and 2^40 wraps, a skewed anchor clock, the bucket rule's warm-up, the
 * 30 ms life of remote data, the rotating "random" matching, whole-tick truncation, eviction, tolerant
 * parsing, TDoA3 short entries, and the firmware's RADIO path (RESULT, RADIO_DROP, STATS). */
#include <math.h>
#include <string.h>

#include "fw_wire.h"
#include "lps_packets.h"
#include "tdoa_engine.h"
#include "unit.h"

#define MASK32 0xFFFFFFFFull
#define MASK40 0xFFFFFFFFFFull
#define STEP_TICKS 639976000ull          /* 10 ms */
#define TOF01 33000u
#define M_PER_TICK (TDOA_SPEED_OF_LIGHT / TDOA_TS_FREQ)

static const uint64_t tag_range[2] = {5000u, 5800u};        /* ticks, antenna delay included */
static const uint64_t offset[2] = {0x12345678ull, 0xF0000000ull};

typedef struct {
    uint64_t last_t[2];
    uint8_t seq[2], has[2];
    double skew1;     /* anchor 1's clock rate - 1 */
} scen_t;

static uint64_t anchor_clock(const scen_t *s, int a, uint64_t t)
{
    return a == 1 ? offset[1] + (uint64_t)llround((double)t * (1.0 + s->skew1)) : offset[0] + t;
}

static void put32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

/* TDoA3 packet of anchor a at global tick t (full entry for the other anchor if it was heard; short
 * entry when `short_entry`), LPP position appended when `lpp`. Returns the length. */
static size_t tdoa3_packet(scen_t *s, int a, uint64_t t, int short_entry, int lpp, uint8_t *p)
{
    const int b = 1 - a;
    size_t n = 7;
    p[0] = LPS_TYPE_TDOA3;
    p[1] = s->seq[a];
    put32(p + 2, (uint32_t)(anchor_clock(s, a, t) & MASK32));
    p[6] = s->has[b];
    if (s->has[b]) {
        p[n] = (uint8_t)b;
        p[n + 1] = (uint8_t)(((s->seq[b] - 1u) & 0x7Fu) | (short_entry ? 0u : 0x80u));
        put32(p + n + 2, (uint32_t)(anchor_clock(s, a, s->last_t[b] + TOF01) & MASK32));
        n += 6;
        if (!short_entry) {
            p[n] = (uint8_t)(TOF01 & 0xFF);
            p[n + 1] = (uint8_t)(TOF01 >> 8);
            n += 2;
        }
    }
    if (lpp) {
        const float pos[3] = {(float)a, 2.0f, 1.5f};
        p[n] = LPS_LPP_SHORT;
        p[n + 1] = LPS_LPP_POSITION;
        memcpy(p + n + 2, pos, sizeof pos);
        n += 14;
    }
    s->last_t[a] = t;
    s->has[a] = 1;
    s->seq[a] = (uint8_t)((s->seq[a] + 1) & 0x7F);
    return n;
}

static int feed(tdoa_engine_t *e, scen_t *s, int a, uint64_t t, int short_entry, tdoa_meas_t *m)
{
    uint8_t p[128];
    lps_packet_t pkt;
    size_t n = tdoa3_packet(s, a, t, short_entry, 0, p);
    CHECK(lps_parse(p, n, (uint8_t)a, &pkt) == LPS_OK);
    return tdoa_engine_process(e, &pkt, (uint8_t)a, (t + tag_range[a]) & MASK40, t / 63898u, TDOA_MATCH_AUTO, m);
}

static void test_exact_across_wraps(void)
{
    static tdoa_engine_t e;
    scen_t s;
    tdoa_meas_t m;
    const uint64_t base = (1ull << 40) - 20 * STEP_TICKS;  /* the tag's counter wraps mid-sequence */
    int k, meas = 0, clock = 0;
    memset(&s, 0, sizeof s);
    tdoa_engine_init(&e);
    for (k = 0; k < 60; k++) {
        int a = k % 2;
        int rc = feed(&e, &s, a, base + (uint64_t)k * STEP_TICKS, k % 4 == 3, &m);
        if (rc == TDOA_MEASUREMENT) {
            const double want = ((double)tag_range[a] - (double)tag_range[1 - a]) * M_PER_TICK;
            meas++;
            CHECK(m.anchor_b == a && m.anchor_a == 1 - a);
            CHECK_NEAR(tdoa_metres(m.ticks), want, 1e-9);
        } else {
            clock += rc == TDOA_DROP_CLOCK;
        }
    }
    CHECK(clock == 4);          /* two packets per anchor before its clock correction is reliable */
    CHECK(meas == 56);
    CHECK(tdoa_engine_anchor(&e, 0)->bucket == TDOA_CC_BUCKET_MAX);
    CHECK_NEAR((double)tdoa_engine_anchor(&e, 1)->cc / (double)TDOA_CC_ONE, 1.0, 1e-15);
}

static void test_skewed_anchor_clock(void)
{
    static tdoa_engine_t e;
    scen_t s;
    tdoa_meas_t m;
    int k, meas = 0;
    memset(&s, 0, sizeof s);
    s.skew1 = 8e-6;
    tdoa_engine_init(&e);
    for (k = 0; k < 40; k++) {
        int a = k % 2;
        if (feed(&e, &s, a, 5000000000ull + (uint64_t)k * STEP_TICKS, 0, &m) == TDOA_MEASUREMENT) {
            const double want = ((double)tag_range[a] - (double)tag_range[1 - a]) * M_PER_TICK;
            meas++;
            /* stored in whole ticks (truncated toward zero, as a Crazyflie: test_bitcraze_parity.py) */
            CHECK_NEAR(tdoa_metres(m.ticks), TDOA_SPEED_OF_LIGHT * (double)m.ticks / TDOA_TS_FREQ, 1e-15);
            CHECK_NEAR(tdoa_metres_f(m.ticks), tdoa_metres(m.ticks), 1e-6 * fabs(tdoa_metres(m.ticks)));
            CHECK_NEAR(tdoa_metres(m.ticks), want, 2.0 * M_PER_TICK);   /* integer stamps: within two ticks */
        }
    }
    CHECK(meas == 36);
    CHECK_NEAR((double)tdoa_engine_anchor(&e, 1)->cc / (double)TDOA_CC_ONE, 1.0 / (1.0 + 8e-6), 2e-9);   /* 0.002 ppm: tick rounding */
}

/* Remote data lives 30 ms (whole ms of tag time): a packet without entries still finds the reference
 * its previous packet reported, until then. */
static void test_remote_data_expires_after_30_ms(void)
{
    static tdoa_engine_t e;
    scen_t s;
    tdoa_meas_t m;
    lps_packet_t pkt;
    uint8_t p[7] = {LPS_TYPE_TDOA3, 0, 0, 0, 0, 0, 0};
    int k;
    memset(&s, 0, sizeof s);
    tdoa_engine_init(&e);
    for (k = 0; k < 8; k++) {
        feed(&e, &s, k % 2, (uint64_t)(k + 1) * STEP_TICKS, 0, &m);   /* anchor 1 last at 80 ms */
    }
    for (k = 0; k < 2; k++) {       /* anchor 1 again, no entries: 29 ms after its last packet, then 31 */
        const uint64_t t_us = (uint64_t)(8 * 10000 + 29000 + 2000 * k);
        const uint32_t tx = (uint32_t)(anchor_clock(&s, 1, t_us * 63898u) & MASK32);
        p[1] = s.seq[1];
        put32(p + 2, tx);
        CHECK(lps_parse(p, sizeof p, 1, &pkt) == LPS_OK);
        s.seq[1]++;
        /* its clock is consistent: only the expiry decides */
        CHECK(tdoa_engine_process(&e, &pkt, 1, (t_us * 63898u + tag_range[1]) & MASK40, t_us, TDOA_MATCH_AUTO, &m) ==
              (k == 0 ? TDOA_MEASUREMENT : TDOA_DROP_NO_REFERENCE));
    }
}

/* Three anchors at ideal clocks: anchor 2 reports 0 and 1, both valid references; "random" alternates
 * them (the start rotates by one per search), "youngest" takes the one heard last. */
static void test_matching(void)
{
    static tdoa_engine_t e;
    int mode, k;
    for (mode = TDOA_MATCH_RANDOM; mode <= TDOA_MATCH_YOUNGEST; mode++) {
        int refs[2] = {0, 0};
        tdoa_engine_init(&e);
        for (k = 0; k < 30; k++) {
            const int a = k % 3;
            const uint64_t t = 1000000000ull + (uint64_t)k * STEP_TICKS;
            uint8_t p[7 + 2 * 8];
            size_t n = 7;
            int b;
            lps_packet_t pkt;
            tdoa_meas_t m;
            p[0] = LPS_TYPE_TDOA3;
            p[1] = (uint8_t)(k / 3);
            put32(p + 2, (uint32_t)(t & MASK32));
            p[6] = 2;
            for (b = 0; b < 3; b++) {
                const int kb = k - ((a - b + 3) % 3);     /* b's last transmission */
                if (b == a) {
                    continue;
                }
                p[n] = (uint8_t)b;
                p[n + 1] = (uint8_t)(0x80u | (kb >= 0 ? (unsigned)(kb / 3) : 0u));
                put32(p + n + 2, (uint32_t)((1000000000ull + (uint64_t)kb * STEP_TICKS + TOF01) & MASK32));
                p[n + 6] = (uint8_t)(TOF01 & 0xFF);
                p[n + 7] = (uint8_t)(TOF01 >> 8);
                n += 8;
            }
            CHECK(lps_parse(p, n, (uint8_t)a, &pkt) == LPS_OK);
            if (tdoa_engine_process(&e, &pkt, (uint8_t)a, t + 5000, t / 63898u, mode, &m) == TDOA_MEASUREMENT) {
                CHECK(m.ticks == 0 && m.anchor_b == a);
                if (a == 2) {
                    refs[m.anchor_a]++;
                }
            }
        }
        if (mode == TDOA_MATCH_RANDOM) {
            CHECK(refs[0] > 0 && refs[1] > 0 && refs[0] + refs[1] >= 7);
        } else {
            CHECK(refs[0] == 0 && refs[1] >= 7);      /* 1 transmitted after 0 */
        }
    }
}

static void test_eviction_and_parsing(void)
{
    static tdoa_engine_t e;
    lps_packet_t pkt;
    tdoa_meas_t m;
    uint8_t p[128] = {LPS_TYPE_TDOA3, 0, 1, 0, 0, 0, 0};
    unsigned id, k;
    tdoa_engine_init(&e);
    for (id = 0; id <= TDOA_STORAGE_COUNT; id++) {
        CHECK(lps_parse(p, 7, (uint8_t)id, &pkt) == LPS_OK);
        CHECK(tdoa_engine_process(&e, &pkt, (uint8_t)id, 1000u * id, 1000u * id, TDOA_MATCH_AUTO, &m) == TDOA_DROP_CLOCK);
    }
    CHECK(tdoa_engine_anchor(&e, 0) == NULL);      /* the one heard longest ago made room */
    CHECK(tdoa_engine_anchor(&e, 1) != NULL && tdoa_engine_anchor(&e, TDOA_STORAGE_COUNT) != NULL);
    p[6] = 1;                                      /* one entry announced, none there: a packet all the same */
    CHECK(lps_parse(p, 7, 3, &pkt) == LPS_OK && pkt.n_remote == 0);
    p[6] = 12;                                     /* 12 short entries (more than 8), one of them the sender */
    for (k = 0; k < 12; k++) {
        p[7 + 6 * k] = (uint8_t)(k == 5 ? 3 : 100 + k);
        p[8 + 6 * k] = (uint8_t)k;
        put32(p + 9 + 6 * k, 1000u + k);
    }
    p[79] = 0xAB;                                  /* and a trailing byte */
    CHECK(lps_parse(p, 80, 3, &pkt) == LPS_OK && pkt.n_remote == 11 && pkt.remote[10].id == 111);
    CHECK(pkt.remote[5].id == 106 && pkt.remote[0].tof == 0 && !pkt.has_pos);
    CHECK(lps_parse(p, 78, 3, &pkt) == LPS_OK && pkt.n_remote == 10);   /* the truncated 12th is left out */
    p[0] = 0x31;
    CHECK(lps_parse(p, 7, 3, &pkt) == LPS_ERR_UNKNOWN_TYPE);
    CHECK(lps_parse(p, 0, 3, &pkt) == LPS_ERR_MALFORMED);
    p[0] = LPS_TYPE_TDOA3;
    CHECK(lps_parse(p, 6, 3, &pkt) == LPS_ERR_MALFORMED);
    p[0] = LPS_TYPE_TDOA2;
    CHECK(lps_parse(p, 57, 8, &pkt) == LPS_ERR_MALFORMED && lps_parse(p, 56, 2, &pkt) == LPS_ERR_MALFORMED);
}

/* ------------------------------------------------------------------- the firmware's RADIO path */
static wire_sink_t sink;
static firmware_t fw;

static void count_replies(int *results, int *drops)
{
    size_t pos = 0;
    uwb_msg_t msg;
    *results = *drops = 0;
    while (wire_next(&sink, &pos, &msg)) {
        *results += msg.type == UWB_MSG_RESULT;
        *drops += msg.type == UWB_MSG_RADIO_DROP;
    }
}

static void test_firmware_radio_path(void)
{
    scen_t s;
    int k, results, drops;
    memset(&s, 0, sizeof s);
    sink.len = 0;
    firmware_init(&fw, wire_sink_write, &sink, "test");
    for (k = 0; k < 20; k++) {
        uwb_msg_t msg;
        const int a = k % 2;
        const uint64_t t = 7000000000ull + (uint64_t)k * STEP_TICKS;
        memset(&msg, 0, sizeof msg);
        msg.type = UWB_MSG_RADIO;
        msg.seq = (uint16_t)k;
        msg.u.radio.t_us = 1000u + 10000u * (uint64_t)k;
        msg.u.radio.rx_ts = (t + tag_range[a]) & MASK40;
        msg.u.radio.src_addr = 0xBCCF000000000000ull | (uint64_t)a;
        msg.u.radio.length = (uint8_t)tdoa3_packet(&s, a, t, 0, 1, msg.u.radio.payload);
        wire_send(&fw, &msg);
    }
    count_replies(&results, &drops);
    CHECK(results == 16 && drops == 4);
    CHECK(fw.stats.radio_packets == 20 && fw.stats.radio_meas == 16 && fw.stats.radio_clock == 4);
    CHECK(fw.stats.results == 16);
    CHECK((fw.est.anchor_known & 3u) == 3u);        /* positions from the packets' LPP */
    CHECK_NEAR(fw.est.anchors[1][0], 1.0, 0.0);
}

int main(void)
{
    RUN(test_exact_across_wraps);
    RUN(test_skewed_anchor_clock);
    RUN(test_remote_data_expires_after_30_ms);
    RUN(test_matching);
    RUN(test_eviction_and_parsing);
    RUN(test_firmware_radio_path);
    return UNIT_DONE();
}
