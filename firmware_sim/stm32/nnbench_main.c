/* uwb-nnbench: the compiled-in bias networks run by three kernels on inputs sent by the host, with
 * the instruction count of each call (TIM2 under QEMU -icount shift=0). Used by harness/bench/qemu.py
 * to measure the M4 kernels against the core's portable version in the same run, and to check their
 * outputs against PyTorch.
 *
 * Binary protocol on the link USART (little endian, no framing: fixed-size messages):
 *   host 'I'                         -> 'i' n_in_twr:u8 n_in_tdoa:u8 layout_twr:u8 layout_tdoa:u8
 *   host 'P' kind:u8 x:f32[n_in]     -> 'p' y:f32[3] cost:u32[3]
 *        kind 0 = TWR net, 1 = TDoA net; kernels in order: portable (core), C blocked, assembly.
 *        cost = instructions of the call, the cost of reading the clock subtracted.
 *   host 'W' kind:u8                 -> 'w' n_in:u8 then f32: in_min[n_in] in_max[n_in] w1[n_in*50] b1[50]
 *                                       w2[50*50] b2[50] w3[50] b3 out_min out_max
 *        (the compiled-in tables, so the host can run the same network in PyTorch)
 *   anything else                    -> '?' */
#include <string.h>

#include "board.h"
#include "nn_m4.h"
#include "platform.h"
#include "stm32f405_regs.h"

typedef float (*predict_fn)(const bias_nn_t *net, const float *features, float *std_out);

static void read_exact(uint8_t *dst, size_t n)
{
    while (n > 0u) {
        const uint8_t *data;
        size_t got = usart_rx_wait(&data);
        if (got > n) {
            got = n;
        }
        memcpy(dst, data, got);
        usart_rx_release(got);
        dst += got;
        n -= got;
    }
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

static uint32_t clock_overhead;

static uint32_t timed(predict_fn fn, const bias_nn_t *net, const float *x, float *y)
{
    uint32_t t0, t1;
    t0 = platform_cost_now();
    *y = fn(net, x, (float *)0);
    t1 = platform_cost_now();
    return (t1 - t0) - clock_overhead;
}

static void calibrate(void)
{
    uint32_t t0 = platform_cost_now();
    uint32_t t1 = platform_cost_now();
    clock_overhead = t1 - t0;
}

/* The network of the kind byte that follows a command (0 TWR, 1 TDoA); NULL, with '?' replied, if absent or
 * q15 (bias_nn.h: the float32 kernels measured here do not apply; its SMLAD kernel runs in uwb-fw.elf). */
static const bias_nn_t *read_net(const bias_model_t *model)
{
    uint8_t kind;
    const bias_nn_t *net;
    read_exact(&kind, 1);
    net = kind == 0u ? model->twr : model->tdoa;
    if (net == (const bias_nn_t *)0 || net->q_heads > 0u) {
        const uint8_t q = '?';
        usart_write(&q, 1);
        return (const bias_nn_t *)0;
    }
    return net;
}

/* 'I': the input counts and feature layouts of both networks (0 where a network is absent). */
static void reply_info(const bias_model_t *model)
{
    uint8_t out[5];
    out[0] = 'i';
    out[1] = model->twr ? model->twr->n_in : 0u;
    out[2] = model->tdoa ? model->tdoa->n_in : 0u;
    out[3] = model->twr ? model->twr->layout : 0u;
    out[4] = model->tdoa ? model->tdoa->layout : 0u;
    usart_write(out, sizeof out);
}

/* 'P' kind x[n_in]: each kernel's output bits and instruction count. */
static void reply_predict(const bias_model_t *model)
{
    static const predict_fn kernels[3] = {__real_bias_nn_predict, nn_m4_predict_c, nn_m4_predict};
    const bias_nn_t *net = read_net(model);
    float x[BIAS_NN_MAX_IN];
    uint8_t out[1 + 3 * 4 + 3 * 4];
    unsigned k;
    if (net == (const bias_nn_t *)0) {
        return;
    }
    read_exact((uint8_t *)x, 4u * net->n_in);
    out[0] = 'p';
    for (k = 0; k < 3u; k++) {
        float y;
        uint32_t bits, cost = timed(kernels[k], net, x, &y);
        memcpy(&bits, &y, sizeof bits);
        put_u32(&out[1u + 4u * k], bits);
        put_u32(&out[13u + 4u * k], cost);
    }
    usart_write(out, sizeof out);
}

/* 'W' kind: the network's compiled-in tables, in the order the header comment lists. */
static void reply_weights(const bias_model_t *model)
{
    uint8_t head[2];
    const bias_nn_t *net = read_net(model);
    if (net == (const bias_nn_t *)0) {
        return;
    }
    head[0] = 'w';
    head[1] = net->n_in;
    usart_write(head, 2);
    usart_write((const uint8_t *)net->in_min, 4u * net->n_in);
    usart_write((const uint8_t *)net->in_max, 4u * net->n_in);
    usart_write((const uint8_t *)net->w1, 4u * net->n_in * BIAS_NN_HIDDEN);
    usart_write((const uint8_t *)net->b1, 4u * BIAS_NN_HIDDEN);
    usart_write((const uint8_t *)net->w2, 4u * BIAS_NN_HIDDEN * BIAS_NN_HIDDEN);
    usart_write((const uint8_t *)net->b2, 4u * BIAS_NN_HIDDEN);
    usart_write((const uint8_t *)net->w3, 4u * BIAS_NN_HIDDEN);
    usart_write((const uint8_t *)&net->b3, 4u);
    usart_write((const uint8_t *)&net->out_min, 4u);
    usart_write((const uint8_t *)&net->out_max, 4u);
}

int main(void)
{
    board_clocks_t clk;
    const bias_model_t *model = &bias_model_compiled;

    board_clock_init(&clk);
    platform_stm32_init(&clk);
    usart_init(&clk, UWB_BAUD);
    calibrate();

    for (;;) {
        uint8_t cmd;
        read_exact(&cmd, 1);
        if (cmd == 'I') {
            reply_info(model);
        } else if (cmd == 'P') {
            reply_predict(model);
        } else if (cmd == 'W') {
            reply_weights(model);
        } else {
            uint8_t q = '?';
            usart_write(&q, 1);
        }
    }
}
