/* uwb-protobench: instructions per frame of the firmware's protocol path, on the STM32 build under QEMU
 * (TIM2 under -icount shift=0 counts executed instructions; exact and identical from run to run).
 * harness/bench/qemu_proto.py runs it and `make bench` prints its figures.
 *
 * Frames are built in the guest from fixed messages (an IMU sample, a TDoA measurement, a RESULT), then
 * each path is timed (the cost of reading the clock subtracted):
 *   rx_bytes:  the byte-at-a-time receiver: frame_rx_push per byte, cobs_decode, uwb_body_decode (CRC, decode)
 *   rx_block:  what firmware_feed runs: frame_rx_feed over the whole buffer, uwb_body_decode in its sink
 *   tx_copy:   uwb_body_encode into a body buffer, cobs_encode into a second one, delimiter
 *   tx_frame:  what fw_send_msg runs: uwb_frame_encode (body packed in place, COBS in place, delimiter)
 * Output (ARM semihosting console, then SYS_EXIT): one line per figure, "<path> <message> <instructions>",
 * then "ok". A path that does not give back the message it was fed prints "FAIL <path> <message>".
 * Semihosting is QEMU-only: never flash this image. */
#include <string.h>

#include "board.h"
#include "cobs.h"
#include "frame_rx.h"
#include "frame_tx.h"
#include "platform.h"
#include "uwb_msgs.h"

#define SYS_WRITE0 0x04u
#define SYS_EXIT 0x18u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

typedef struct {
    const char *name;
    uwb_msg_t msg;
    uint8_t enc[UWB_MAX_ENCODED + 1];
    size_t enc_len; /* with the delimiter */
} sample_t;

static uint32_t clock_overhead;
static uwb_msg_t decoded;
static int decoded_ok;

static uint32_t semihost(uint32_t op, const void *args)
{
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = args;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static void print_line(const char *a, const char *b, uint32_t v)
{
    char text[80], digits[10];
    size_t n = 0, k = 0;
    while (*a != '\0') {
        text[n++] = *a++;
    }
    text[n++] = ' ';
    while (*b != '\0') {
        text[n++] = *b++;
    }
    text[n++] = ' ';
    do {
        digits[k++] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v != 0u);
    while (k != 0u) {
        text[n++] = digits[--k];
    }
    text[n++] = '\n';
    text[n] = '\0';
    (void)semihost(SYS_WRITE0, text);
}

static void rx_bytes(const uint8_t *data, size_t n)
{
    static frame_rx_t rx;
    size_t i;
    for (i = 0; i < n; i++) {
        const uint8_t *frame;
        size_t len;
        if (frame_rx_push(&rx, data[i], &frame, &len) == FRAME_RX_FRAME) {
            uint8_t body[UWB_MAX_BODY];
            long m = cobs_decode(frame, len, body, sizeof body);
            decoded_ok = m >= 0 && uwb_body_decode(body, (size_t)m, &decoded) == UWB_DECODE_OK;
        }
    }
}

static void block_sink(void *ctx, frame_rx_event_t ev, const uint8_t *body, size_t len)
{
    (void)ctx;
    decoded_ok = ev == FRAME_RX_FRAME && uwb_body_decode(body, len, &decoded) == UWB_DECODE_OK;
}

static void rx_block(const uint8_t *data, size_t n)
{
    static frame_rx_t rx;
    frame_rx_feed(&rx, data, n, block_sink, NULL);
}

static void tx_frame(const uwb_msg_t *msg, uint8_t *out)
{
    (void)uwb_frame_encode(msg, out);
}

static void tx_copy(const uwb_msg_t *msg, uint8_t *out)
{
    uint8_t body[UWB_MAX_BODY];
    size_t n = uwb_body_encode(msg, body);
    size_t m = cobs_encode(body, n, out);
    out[m] = 0;
}

typedef void (*rx_fn)(const uint8_t *data, size_t n);

static void time_rx(const char *path, rx_fn fn, const sample_t *s)
{
    uint32_t t0, t1;
    decoded_ok = 0;
    t0 = platform_cost_now();
    fn(s->enc, s->enc_len);
    t1 = platform_cost_now();
    if (!decoded_ok || decoded.type != s->msg.type || decoded.seq != s->msg.seq) {
        print_line("FAIL", path, 0u);
        return;
    }
    print_line(path, s->name, (t1 - t0) - clock_overhead);
}

typedef void (*tx_fn)(const uwb_msg_t *msg, uint8_t *out);

static void time_tx(const char *path, tx_fn fn, const sample_t *s)
{
    uint8_t out[UWB_MAX_ENCODED + 1];
    uint32_t t0, t1;
    memset(out, 0xEE, sizeof out);
    t0 = platform_cost_now();
    fn(&s->msg, out);
    t1 = platform_cost_now();
    if (memcmp(out, s->enc, s->enc_len) != 0) {
        print_line("FAIL", path, 0u);
        return;
    }
    print_line(path, s->name, (t1 - t0) - clock_overhead);
}

static void make_sample(sample_t *s, const char *name, const uwb_msg_t *msg)
{
    s->name = name;
    s->msg = *msg;
    tx_copy(msg, s->enc);
    s->enc_len = strlen((const char *)s->enc) + 1u; /* an encoded frame holds no 0x00 before its delimiter */
}

static void fill_result(uwb_result_t *r)
{
    /* Typical values of a TDoA update: the floats are what the estimator sends (a few exact zeros). */
    const float f[] = {0.0132f, 0.00461f, -0.0417f, 0.35f, 0.21f, -0.08f, 0.33f, 1.234f, -0.567f, 0.891f,
                       0.012f, -0.034f, 0.0f, 0.9998f, 0.0012f, -0.0151f, 0.0203f, 0.0021f, 0.0019f, 0.0034f,
                       0.011f, 0.012f, 0.015f, 0.0f, 0.0f, 0.0f};
    float *dst[] = {&r->innovation, &r->innovation_var, &r->bias, &r->d_max, &r->gain_x, &r->gain_y, &r->gain_z,
                    &r->px, &r->py, &r->pz, &r->vx, &r->vy, &r->vz, &r->qw, &r->qx, &r->qy, &r->qz,
                    &r->var_x, &r->var_y, &r->var_z, &r->var_vx, &r->var_vy, &r->var_vz,
                    &r->var_d0, &r->var_d1, &r->var_d2};
    size_t i;
    for (i = 0; i < sizeof dst / sizeof dst[0]; i++) {
        *dst[i] = f[i];
    }
    r->meas_seq = 4243u;
    r->t_us = 61234567u;
    r->kind = UWB_MEAS_KIND_TDOA;
    r->status = UWB_STATUS_ACCEPTED;
    r->compute = 9745u;
    r->cost_nn = 0u;
    r->cost_gates = 212u;
    r->cost_update = 4740u;
    r->cost_predict = 1950u;
}

static void make_samples(sample_t *imu, sample_t *tdoa, sample_t *result)
{
    uwb_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_IMU;
    m.seq = 4242u;
    m.u.imu.t_us = 61234000u;
    m.u.imu.ax = 0.123f, m.u.imu.ay = -0.241f, m.u.imu.az = 9.79f;
    m.u.imu.gx = 0.0121f, m.u.imu.gy = -0.0043f, m.u.imu.gz = 0.0311f;
    make_sample(imu, "imu", &m);
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_TDOA;
    m.seq = 4243u;
    m.u.tdoa.t_us = 61234567u;
    m.u.tdoa.anchor_a = 2u, m.u.tdoa.anchor_b = 5u;
    m.u.tdoa.diff = -0.7312f;
    make_sample(tdoa, "tdoa", &m);
    memset(&m, 0, sizeof m);
    m.type = UWB_MSG_RESULT;
    m.seq = 777u;
    fill_result(&m.u.result);
    make_sample(result, "result", &m);
}

int main(void)
{
    static sample_t imu, tdoa, result;
    board_clocks_t clk;
    uint32_t t0, t1;
    board_clock_init(&clk);
    platform_stm32_init(&clk);
    t0 = platform_cost_now();
    t1 = platform_cost_now();
    clock_overhead = t1 - t0;
    make_samples(&imu, &tdoa, &result);
    time_rx("rx_bytes", rx_bytes, &imu);
    time_rx("rx_bytes", rx_bytes, &tdoa);
    time_rx("rx_block", rx_block, &imu);
    time_rx("rx_block", rx_block, &tdoa);
    time_tx("tx_copy", tx_copy, &result);
    time_tx("tx_frame", tx_frame, &result);
    (void)semihost(SYS_WRITE0, "ok\n");
    (void)semihost(SYS_EXIT, (const void *)ADP_STOPPED_APPLICATION_EXIT);
    for (;;) {
    }
}
