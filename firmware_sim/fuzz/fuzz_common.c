#include <stdio.h>
#include <stdlib.h>

#include "cobs.h"
#include "fuzz_common.h"
#include "uwb_msgs.h"

void fuzz_fail(const char *what)
{
    fprintf(stderr, "fuzz invariant violated: %s\n", what);
    abort();
}

void out_checker_init(out_checker_t *oc)
{
    frame_rx_init(&oc->rx);
    oc->frames = oc->results = oc->errors = oc->stats = oc->hello_replies = 0;
}

static void check_frame(out_checker_t *oc, const uint8_t *enc, size_t n)
{
    uint8_t body[UWB_MAX_BODY];
    uwb_msg_t msg;
    long len = cobs_decode(enc, n, body, sizeof body);
    if (len < 0) {
        fuzz_fail("device sent a frame that is not valid COBS");
    }
    if (uwb_body_decode(body, (size_t)len, &msg) != UWB_DECODE_OK) {
        fuzz_fail("device sent a frame that does not decode (crc, type or length)");
    }
    switch (msg.type) {
    case UWB_MSG_RESULT:
        /* The divergence guard keeps the state finite whatever the input. */
        if (!uwb_msg_finite(&msg)) {
            const uwb_result_t *r = &msg.u.result;
            fprintf(stderr, "RESULT status %u y %g S %g bias %g d_max %g K %g %g %g p %g %g %g v %g %g %g "
                    "var %g %g %g %g %g %g %g %g %g\n", r->status, r->innovation, r->innovation_var,
                    r->bias, r->d_max, r->gain_x, r->gain_y, r->gain_z, r->px, r->py, r->pz, r->vx, r->vy,
                    r->vz, r->var_x, r->var_y, r->var_z, r->var_vx, r->var_vy, r->var_vz, r->var_d0,
                    r->var_d1, r->var_d2);
            fuzz_fail("RESULT with a non-finite field");
        }
        if (!(msg.u.result.var_x >= 0.0f && msg.u.result.var_y >= 0.0f && msg.u.result.var_z >= 0.0f)) {
            fuzz_fail("RESULT with a negative position variance");
        }
        oc->results++;
        break;
    case UWB_MSG_ERROR:
        oc->errors++;
        break;
    case UWB_MSG_STATS:
        oc->stats++;
        break;
    case UWB_MSG_HELLO_REPLY:
        oc->hello_replies++;
        break;
    default:
        /* Other device -> host types (ids 0x80 and up) are fine; host -> device ones are not. */
        if (!(msg.type & 0x80u)) {
            fuzz_fail("device sent a host -> device message type");
        }
        break;
    }
    oc->frames++;
}

void out_checker_feed(out_checker_t *oc, const uint8_t *data, size_t n)
{
    size_t i;
    for (i = 0; i < n; i++) {
        const uint8_t *frame = NULL;
        size_t len = 0;
        switch (frame_rx_push(&oc->rx, data[i], &frame, &len)) {
        case FRAME_RX_FRAME:
            check_frame(oc, frame, len);
            break;
        case FRAME_RX_OVERSIZE:
            fuzz_fail("device sent an oversize frame");
            break;
        default:
            if (data[i] == 0) {
                fuzz_fail("device sent an empty frame");
            }
            break;
        }
    }
}
