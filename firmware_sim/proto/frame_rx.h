/* Byte-stream frame receiver: collects bytes up to each 0x00 delimiter, never overflows.
 * Two interfaces over the same state: frame_rx_push() takes one byte and hands back the COBS-encoded
 * frame; frame_rx_feed() takes whatever block the link has, finds the delimiters a word at a time
 * (zero_bytes.h) and hands each frame COBS-decoded to a sink (what the firmware uses: a few hundred instructions less per
 * frame than a call and a state-machine step per byte). Both report the same frames, oversize frames
 * and (push + cobs_decode) undecodable frames for every byte sequence, however it is cut into blocks
 * (fuzz/fuzz_frame_rx.c checks this). */
#ifndef UWB_FRAME_RX_H
#define UWB_FRAME_RX_H

#include <stddef.h>
#include <stdint.h>

#include "uwb_msgs.h"

typedef struct {
    uint8_t buf[UWB_MAX_ENCODED];
    size_t len;
    uint8_t overflow; /* current frame exceeded UWB_MAX_ENCODED: discard until the next delimiter */
} frame_rx_t;

typedef enum {
    FRAME_RX_NONE = 0,   /* byte consumed, no frame complete */
    FRAME_RX_FRAME,      /* *frame / *len hold a complete COBS-encoded frame */
    FRAME_RX_OVERSIZE,   /* a delimiter ended a frame that was too long (discarded) */
    FRAME_RX_BAD_COBS    /* frame_rx_feed only: a frame that is not valid COBS (cobs_decode fails) */
} frame_rx_event_t;

/* ev FRAME_RX_FRAME: body/len the COBS-decoded frame (header + payload + crc, not yet checked);
 * FRAME_RX_OVERSIZE or FRAME_RX_BAD_COBS: len 0. body is valid during the call only. */
typedef void (*frame_rx_sink_fn)(void *ctx, frame_rx_event_t ev, const uint8_t *body, size_t len);

void frame_rx_init(frame_rx_t *rx);
frame_rx_event_t frame_rx_push(frame_rx_t *rx, uint8_t byte, const uint8_t **frame, size_t *len);
/* Feed n bytes: sink is called once per delimiter that ends a non-empty frame, in order; a frame cut
 * across blocks is kept in rx until its delimiter arrives. The sink must not feed rx. */
void frame_rx_feed(frame_rx_t *rx, const uint8_t *data, size_t n, frame_rx_sink_fn sink, void *ctx);

#endif
