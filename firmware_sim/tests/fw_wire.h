/* Test-side wire helpers shared by the firmware-level C tests: a byte sink the firmware writes its
 * frames to, and one message framed (body + COBS + 0 delimiter) and fed in. */
#ifndef UWB_FW_WIRE_H
#define UWB_FW_WIRE_H

#include <string.h>

#include "cobs.h"
#include "firmware.h"
#include "uwb_msgs.h"

typedef struct {
    uint8_t data[1 << 20]; /* large enough for every test's replies; bytes past it are dropped */
    size_t len;
} wire_sink_t;

static inline void wire_sink_write(void *ctx, const uint8_t *d, size_t n)
{
    wire_sink_t *s = (wire_sink_t *)ctx;
    if (s->len + n <= sizeof s->data) {
        memcpy(s->data + s->len, d, n);
        s->len += n;
    }
}

/* msg as one frame with its 0 delimiter in out (UWB_MAX_ENCODED + 1 bytes); returns its length. */
static inline size_t wire_frame(const uwb_msg_t *msg, uint8_t *out)
{
    uint8_t body[UWB_MAX_BODY];
    size_t n = uwb_body_encode(msg, body);
    size_t m = cobs_encode(body, n, out);
    out[m++] = 0;
    return m;
}

static inline void wire_send(firmware_t *fw, const uwb_msg_t *msg)
{
    uint8_t f[UWB_MAX_ENCODED + 1];
    firmware_feed(fw, f, wire_frame(msg, f));
}

/* The next frame in the sink from *pos that decodes, in *out (frames that do not decode are skipped);
 * 0 when none is left. Start with *pos = 0. */
static inline int wire_next(const wire_sink_t *s, size_t *pos, uwb_msg_t *out)
{
    size_t i;
    for (i = *pos; i < s->len; i++) {
        if (s->data[i] == 0) {
            uint8_t body[UWB_MAX_BODY];
            long n = cobs_decode(s->data + *pos, i - *pos, body, sizeof body);
            *pos = i + 1;
            if (n > 0 && uwb_body_decode(body, (size_t)n, out) == UWB_DECODE_OK) {
                return 1;
            }
        }
    }
    return 0;
}

#endif
