/* libFuzzer target 3: the tag's radio path without the wire protocol: a sequence of packets
 * [sender u8][rx_ts 5 bytes LE][t_us delta u8][len u8][payload len bytes] into lps_parse and the TDoA
 * engine. Invariants: nothing overflows (ASan), no UB (UBSan), every outcome is a known code, a
 * measurement names the sender as B and a stored anchor as A and has a finite difference within the
 * 32-bit range, the
 * storage never holds an id twice, and buckets stay within their bound. */
#include <math.h>
#include <string.h>

#include "fuzz_common.h"
#include "lps_packets.h"
#include "tdoa_engine.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_storage(const tdoa_engine_t *e)
{
    unsigned i, j;
    for (i = 0; i < TDOA_STORAGE_COUNT; i++) {
        const tdoa_anchor_t *a = &e->anchors[i];
        if (!a->in_use) {
            continue;
        }
        if (a->bucket > TDOA_CC_BUCKET_MAX || (a->cc != 0 && (a->cc < TDOA_CC_ONE / 2u || a->cc > 2u * TDOA_CC_ONE))) {
            fuzz_fail("clock correction out of range");
        }
        for (j = i + 1; j < TDOA_STORAGE_COUNT; j++) {
            if (e->anchors[j].in_use && e->anchors[j].id == a->id) {
                fuzz_fail("anchor stored twice");
            }
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static tdoa_engine_t eng;
    size_t off = 0;
    uint64_t t_us = 0;
    tdoa_engine_init(&eng);
    while (size - off >= 8) {
        const uint8_t sender = data[off];
        uint64_t rx_ts = 0;
        size_t len, k;
        lps_packet_t pkt;
        tdoa_meas_t m;
        int rc;
        for (k = 0; k < 5; k++) {
            rx_ts |= (uint64_t)data[off + 1 + k] << (8 * k);
        }
        t_us += (uint64_t)data[off + 6] * 1000u;
        len = data[off + 7];
        off += 8;
        if (len > size - off) {
            len = size - off;
        }
        rc = lps_parse(data + off, len, sender, &pkt);
        off += len;
        if (rc != LPS_OK) {
            if (rc != LPS_ERR_MALFORMED && rc != LPS_ERR_UNKNOWN_TYPE) {
                fuzz_fail("unknown parse result");
            }
            continue;
        }
        if (pkt.n_remote > LPS_MAX_REMOTE) {
            fuzz_fail("too many remotes");
        }
        rc = tdoa_engine_process(&eng, &pkt, sender, rx_ts, t_us, data[off - 8 + 6] % 3u, &m);
        if (rc != TDOA_MEASUREMENT && rc != TDOA_DROP_NO_REFERENCE && rc != TDOA_DROP_CLOCK) {
            fuzz_fail("unknown engine outcome");
        }
        if (rc == TDOA_MEASUREMENT &&
            (m.anchor_b != sender || tdoa_engine_anchor(&eng, m.anchor_a) == NULL || !isfinite(tdoa_metres_f(m.ticks)) ||
             m.ticks > (int64_t)TDOA_MASK32 || m.ticks < -2 * (int64_t)TDOA_MASK32)) {
            fuzz_fail("inconsistent measurement");
        }
        check_storage(&eng);
    }
    return 0;
}
