/* Byte-stream frame receiver: collects bytes up to each 0x00 delimiter, never overflows. */
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
    FRAME_RX_OVERSIZE    /* a delimiter ended a frame that was too long (discarded) */
} frame_rx_event_t;

void frame_rx_init(frame_rx_t *rx);
frame_rx_event_t frame_rx_push(frame_rx_t *rx, uint8_t byte, const uint8_t **frame, size_t *len);

#endif
