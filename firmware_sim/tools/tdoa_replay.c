/* tdoa_replay: drive lps_parse + the TDoA engine from a text packet stream, without the wire protocol.
 * Used by tests/unit/test_tdoa_engine.py to compare the C engine with its twin (harness/twin/tdoa_engine.py).
 * Input lines (stdin): `P t_us rx_ts sender hexpayload` (hexpayload "-" for an empty payload); argument 1:
 * the matching (protocol enum tdoa_match, default 0 = AUTO).
 * Output per packet: `M a b ticks diff` (a measurement; diff with 17 significant digits) or `D reason`
 * (drop_reason: 4 malformed, 5 unknown type, else the engine's); finally `C id bucket cc packets` per
 * stored anchor, in storage order. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lps_packets.h"
#include "tdoa_engine.h"

static int hexval(int c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'a' && c <= 'f') {
        return c - 'a' + 10;
    }
    return -1;
}

int main(int argc, char **argv)
{
    const int match = argc > 1 ? atoi(argv[1]) : TDOA_MATCH_AUTO;
    static char line[1024];
    static tdoa_engine_t eng;
    unsigned i;
    tdoa_engine_init(&eng);
    while (fgets(line, sizeof line, stdin) != NULL) {
        uint64_t t_us, rx_ts;
        unsigned sender;
        char hex[600];
        uint8_t payload[300];
        size_t n = 0;
        lps_packet_t pkt;
        tdoa_meas_t m;
        int rc;
        if (sscanf(line, "P %" SCNu64 " %" SCNu64 " %u %599s", &t_us, &rx_ts, &sender, hex) != 4) {
            continue;
        }
        if (strcmp(hex, "-") != 0) {
            for (n = 0; hex[2 * n] != '\0' && hex[2 * n + 1] != '\0' && n < sizeof payload; n++) {
                payload[n] = (uint8_t)(hexval(hex[2 * n]) * 16 + hexval(hex[2 * n + 1]));
            }
        }
        rc = lps_parse(payload, n, (uint8_t)sender, &pkt);
        if (rc != LPS_OK) {
            printf("D %d\n", rc == LPS_ERR_UNKNOWN_TYPE ? TDOA_DROP_UNKNOWN_TYPE : TDOA_DROP_MALFORMED);
            continue;
        }
        rc = tdoa_engine_process(&eng, &pkt, (uint8_t)sender, rx_ts, t_us, match, &m);
        if (rc == TDOA_MEASUREMENT) {
            printf("M %u %u %" PRId64 " %.17g\n", (unsigned)m.anchor_a, (unsigned)m.anchor_b, m.ticks, tdoa_metres(m.ticks));
        } else {
            printf("D %d\n", rc);
        }
    }
    for (i = 0; i < TDOA_STORAGE_COUNT; i++) {
        const tdoa_anchor_t *a = &eng.anchors[i];
        if (a->in_use) {
            printf("C %u %u %.17g %" PRIu32 "\n", (unsigned)a->id, (unsigned)a->bucket,
                   (double)a->cc / (double)TDOA_CC_ONE, a->packets);
        }
    }
    return 0;
}
