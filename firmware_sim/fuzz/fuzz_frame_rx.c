/* libFuzzer target 1: the frame parser chain on arbitrary bytes: frame_rx -> COBS decode -> body
 * decode (crc, type, length) -> finiteness. Invariants: nothing overflows (ASan), no UB (UBSan),
 * frames never exceed UWB_MAX_ENCODED, a decoded message re-encodes to the very same bytes, and
 * every byte is accounted for (frame bytes + delimiters + oversize bytes = input length). The block
 * receiver (frame_rx_feed, what the firmware runs) must report exactly what frame_rx_push + cobs_decode
 * report, with the input cut into blocks of varying sizes (derived from the input itself). */
#include <string.h>

#include "cobs.h"
#include "frame_rx.h"
#include "frame_tx.h"
#include "fuzz_common.h"
#include "uwb_msgs.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* What the byte-wise receiver reported, in order, for the block receiver to match. */
typedef struct {
    frame_rx_event_t ev;
    size_t len;
    uint32_t crc; /* of the decoded body */
} expect_t;

typedef struct {
    expect_t ev[4096];
    size_t n, next;
} expected_t;

static expected_t expected;

static void expect(frame_rx_event_t ev, const uint8_t *body, size_t len)
{
    expect_t *e = &expected.ev[expected.n++];
    e->ev = ev;
    e->len = len;
    e->crc = ev == FRAME_RX_FRAME ? uwb_crc32c(body, len) : 0u;
}

static void block_sink(void *ctx, frame_rx_event_t ev, const uint8_t *body, size_t len)
{
    const expect_t *e;
    (void)ctx;
    if (expected.next >= expected.n) {
        fuzz_fail("frame_rx_feed reported more frames than frame_rx_push");
    }
    e = &expected.ev[expected.next++];
    if (e->ev != ev || e->len != len || (ev == FRAME_RX_FRAME && uwb_crc32c(body, len) != e->crc)) {
        fuzz_fail("frame_rx_feed differs from frame_rx_push + cobs_decode");
    }
}

static void check_block_receiver(const uint8_t *data, size_t size)
{
    frame_rx_t rx;
    size_t pos = 0;
    uint32_t cut = (uint32_t)size * 2654435761u;
    frame_rx_init(&rx);
    expected.next = 0;
    while (pos < size) {
        size_t k = 1u + (cut >> 24) % 300u; /* blocks of 1..300 bytes: frames cut anywhere */
        cut = cut * 1664525u + 1013904223u;
        if (k > size - pos) {
            k = size - pos;
        }
        frame_rx_feed(&rx, data + pos, k, block_sink, NULL);
        pos += k;
    }
    if (expected.next != expected.n) {
        fuzz_fail("frame_rx_feed reported fewer frames than frame_rx_push");
    }
}

/* One received frame: its COBS decode is what the block receiver must report; a decodable message
 * re-encodes (body, COBS, the firmware's one-buffer encoder) to the very bytes received. */
static void check_frame(const uint8_t *frame, size_t len)
{
    uint8_t body[UWB_MAX_BODY], again[UWB_MAX_BODY], enc[UWB_MAX_ENCODED + 1];
    uwb_msg_t msg;
    long n = cobs_decode(frame, len, body, sizeof body);
    expect(n < 0 ? FRAME_RX_BAD_COBS : FRAME_RX_FRAME, body, n < 0 ? 0u : (size_t)n);
    if (n >= 0 && uwb_body_decode(body, (size_t)n, &msg) == UWB_DECODE_OK) {
        size_t m = uwb_body_encode(&msg, again);
        (void)uwb_msg_finite(&msg);
        if (m != (size_t)n || memcmp(again, body, m) != 0) {
            fuzz_fail("decode -> encode is not the identity");
        }
        /* COBS is canonical for these lengths: re-encoding gives back the input frame. */
        if (cobs_encode(again, m, enc) != len || memcmp(enc, frame, len) != 0) {
            fuzz_fail("COBS re-encode differs from the received frame");
        }
        /* The firmware's one-buffer encoder gives the same frame, delimiter included. */
        if (uwb_frame_encode(&msg, enc) != len + 1 || memcmp(enc, frame, len) != 0 || enc[len] != 0) {
            fuzz_fail("uwb_frame_encode differs from the received frame");
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    frame_rx_t rx;
    size_t i, accounted = 0, since_delim = 0;
    frame_rx_init(&rx);
    expected.n = 0;
    for (i = 0; i < size; i++) {
        const uint8_t *frame = NULL;
        size_t len = 0;
        frame_rx_event_t ev = frame_rx_push(&rx, data[i], &frame, &len);
        if (data[i] != 0) {
            since_delim++;
            if (ev != FRAME_RX_NONE) {
                fuzz_fail("event on a non-delimiter byte");
            }
            continue;
        }
        accounted += since_delim + 1;
        if (ev == FRAME_RX_FRAME) {
            if (len == 0 || len > UWB_MAX_ENCODED || len != since_delim) {
                fuzz_fail("frame length does not match the bytes since the last delimiter");
            }
            if (memcmp(frame, data + i - len, len) != 0) {
                fuzz_fail("frame bytes differ from the input");
            }
            check_frame(frame, len);
        } else if (ev == FRAME_RX_OVERSIZE) {
            expect(FRAME_RX_OVERSIZE, NULL, 0);
            if (since_delim <= UWB_MAX_ENCODED) {
                fuzz_fail("oversize reported for a frame that fits");
            }
        } else if (since_delim != 0) {
            fuzz_fail("bytes before a delimiter produced no event");
        }
        since_delim = 0;
    }
    if (accounted + since_delim != size) {
        fuzz_fail("byte accounting");
    }
    check_block_receiver(data, size);
    return 0;
}
