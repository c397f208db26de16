/* libFuzzer target 1: the frame parser chain on arbitrary bytes: frame_rx -> COBS decode -> body
 * decode (crc, type, length) -> finiteness. Invariants: nothing overflows (ASan), no UB (UBSan),
 * frames never exceed UWB_MAX_ENCODED, a decoded message re-encodes to the very same bytes, and
 * every byte is accounted for (frame bytes + delimiters + oversize bytes = input length). */
#include <string.h>

#include "cobs.h"
#include "frame_rx.h"
#include "fuzz_common.h"
#include "uwb_msgs.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    frame_rx_t rx;
    size_t i, accounted = 0, since_delim = 0;
    frame_rx_init(&rx);
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
            uint8_t body[UWB_MAX_BODY], again[UWB_MAX_BODY], enc[UWB_MAX_ENCODED + 1];
            uwb_msg_t msg;
            long n;
            if (len == 0 || len > UWB_MAX_ENCODED || len != since_delim) {
                fuzz_fail("frame length does not match the bytes since the last delimiter");
            }
            if (memcmp(frame, data + i - len, len) != 0) {
                fuzz_fail("frame bytes differ from the input");
            }
            n = cobs_decode(frame, len, body, sizeof body);
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
            }
        } else if (ev == FRAME_RX_OVERSIZE) {
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
    return 0;
}
