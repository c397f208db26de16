#include "frame_rx.h"

void frame_rx_init(frame_rx_t *rx)
{
    rx->len = 0;
    rx->overflow = 0;
}

frame_rx_event_t frame_rx_push(frame_rx_t *rx, uint8_t byte, const uint8_t **frame, size_t *len)
{
    if (byte == 0) {
        frame_rx_event_t ev = FRAME_RX_NONE;
        if (rx->overflow) {
            ev = FRAME_RX_OVERSIZE;
        } else if (rx->len > 0) {
            *frame = rx->buf;
            *len = rx->len;
            ev = FRAME_RX_FRAME;
        }
        /* The caller consumes the frame before pushing the next byte, so resetting here is safe. */
        rx->len = 0;
        rx->overflow = 0;
        return ev;
    }
    if (rx->len >= sizeof rx->buf) {
        rx->overflow = 1;
        return FRAME_RX_NONE;
    }
    rx->buf[rx->len++] = byte;
    return FRAME_RX_NONE;
}
