#include "frame_rx.h"

#include <string.h>

#include "zero_bytes.h"

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

/* COBS-decode one frame of n (1..UWB_MAX_ENCODED) bytes that holds no 0x00 (frame_rx_feed cut it at the
 * delimiters): the same result as cobs_decode(enc, n, body, UWB_MAX_BODY). With no 0x00 inside and
 * n < 255 a code 0xFF always runs past the end, so every code but the last stands for a 0x00 and the
 * body is enc[1..n) with a 0x00 at each code's place: one copy, then a walk along the codes. */
static long decode_frame(const uint8_t *enc, size_t n, uint8_t *body)
{
    size_t i = enc[0];
    memcpy(body, enc + 1, n - 1u);
    while (i < n) {
        body[i - 1u] = 0;
        i += enc[i];
    }
    return i == n ? (long)(n - 1u) : -1;
}

static void deliver(const uint8_t *enc, size_t n, frame_rx_sink_fn sink, void *ctx)
{
    uint8_t body[UWB_MAX_BODY];
    long len;
    if (n > UWB_MAX_ENCODED) {
        sink(ctx, FRAME_RX_OVERSIZE, enc, 0);
        return;
    }
    len = decode_frame(enc, n, body);
    if (len < 0) {
        sink(ctx, FRAME_RX_BAD_COBS, enc, 0);
        return;
    }
    sink(ctx, FRAME_RX_FRAME, body, (size_t)len);
}

/* Append a run without delimiter to the partial frame (at most UWB_MAX_ENCODED bytes are kept). */
static void keep(frame_rx_t *rx, const uint8_t *data, size_t n)
{
    if (rx->overflow || n > sizeof rx->buf - rx->len) {
        rx->overflow = 1;
        return;
    }
    memcpy(rx->buf + rx->len, data, n);
    rx->len += n;
}

void frame_rx_feed(frame_rx_t *rx, const uint8_t *data, size_t n, frame_rx_sink_fn sink, void *ctx)
{
    const uint8_t *end = data + n;
    while (data != end) {
        const uint8_t *delim = find_zero(data, end);
        size_t run;
        if (delim == NULL) {
            keep(rx, data, (size_t)(end - data));
            return;
        }
        run = (size_t)(delim - data);
        if (rx->len == 0 && !rx->overflow) {
            if (run > 0) {
                deliver(data, run, sink, ctx); /* the whole frame is in this block: no copy */
            }
        } else {
            keep(rx, data, run);
            if (rx->overflow) {
                sink(ctx, FRAME_RX_OVERSIZE, rx->buf, 0);
            } else {
                deliver(rx->buf, rx->len, sink, ctx);
            }
        }
        rx->len = 0;
        rx->overflow = 0;
        data = delim + 1;
    }
}
