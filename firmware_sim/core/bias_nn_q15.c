/* The bias network in q15 (bias_nn.h: q_heads > 0; harness/biasnet/q15.py computes the tables and its
 * Q15Network computes the same integers for the twin). Portable C99: int32 sums that cannot overflow for
 * any input (the exporter's bound), so the order of the multiply-adds does not matter and every build
 * (host, STM32) gives the same sums to the bit.
 *   x_q = round(x' 2^14) saturated to int16 (x' the min-max scaled input, rounded half away from zero)
 *   h1 = clamp((b1 + sum x_q w1) >> shift1, 0, 32767), h2 likewise
 *   head h: (float)(bh + sum h2 wh) * q_out_scale, then de-scaled and clamped (bias) or expf (std). */
#include "bias_nn.h"

#include <math.h>

#ifndef NULL
#define NULL ((void *)0)
#endif

#define Q15_MAX 32767

static int16_t q15_input(float x)
{
    float v = x * 16384.0f;
    if (fabsf(v) < (float)Q15_MAX) { /* the usual case: no saturation */
        return (int16_t)(int32_t)(v + (v >= 0.0f ? 0.5f : -0.5f));
    }
    if (!(v >= -32768.0f)) {
        v = v != v ? 0.0f : -32768.0f; /* NaN -> 0 */
    }
    if (v > (float)Q15_MAX) {
        v = (float)Q15_MAX;
    }
    v += v >= 0.0f ? 0.5f : -0.5f;
    return (int16_t)(int32_t)v;
}

/* The input pairs (x[2k], x[2k+1]), k < n_pairs, with a nonzero entry, into ks; returns their number. A pair
 * of zeros adds nothing to any int32 sum, and ReLU leaves most hidden units at exactly 0 (docs/qemu.md). */
static unsigned q15_nonzero_pairs(const int16_t *x, unsigned n_pairs, uint8_t *ks)
{
    unsigned k, n = 0;
    for (k = 0; k < n_pairs; k++) {
        if (x[2u * k] != 0 || x[2u * k + 1u] != 0) {
            ks[n++] = (uint8_t)k;
        }
    }
    return n;
}

/* acc[j] = b[j] + sum_i x[i] w[i][j] over the input pairs of x that are not both 0 (n_pairs in all), w in
 * the block-major layout (bias_nn.h). */
static void q15_sums(const int16_t *x, unsigned n_pairs, const int16_t *w, const int32_t *b, unsigned n_out,
                     int32_t *acc)
{
    const unsigned blk = BIAS_NN_Q15_BLOCK(n_out);
    uint8_t ks[BIAS_NN_HIDDEN / 2];
    const unsigned nk = q15_nonzero_pairs(x, n_pairs, ks);
    unsigned j, m;
    for (j = 0; j < n_out; j++) {
        const unsigned first = (j / blk) * n_pairs * blk + j % blk; /* word of pair 0 */
        int32_t s = b[j];
        for (m = 0; m < nk; m++) {
            const unsigned k = ks[m];
            const int16_t *wk = w + 2u * (first + k * blk);
            s += (int32_t)x[2u * k] * wk[0] + (int32_t)x[2u * k + 1u] * wk[1];
        }
        acc[j] = s;
    }
}

/* ReLU and requantisation to int16 activations. */
static void q15_relu(const int32_t *acc, unsigned shift, int16_t *out)
{
    unsigned j;
    for (j = 0; j < BIAS_NN_HIDDEN; j++) {
        const int32_t v = acc[j] > 0 ? acc[j] >> shift : 0;
        out[j] = (int16_t)(v > Q15_MAX ? Q15_MAX : v);
    }
}

unsigned bias_nn_q15_inputs(const bias_nn_t *net, const float *features, int16_t x[BIAS_NN_MAX_IN + 1])
{
    const unsigned n_in = net->n_in <= BIAS_NN_MAX_IN ? net->n_in : (unsigned)BIAS_NN_MAX_IN;
    unsigned i;
    for (i = 0; i < n_in; i++) { /* bias_nn_scale_inputs, then the rounding */
        x[i] = q15_input((features[i] - net->in_min[i]) / (net->in_max[i] - net->in_min[i]));
    }
    x[n_in] = 0; /* the pad of an odd input count */
    return (n_in + 1u) / 2u;
}

float bias_nn_q15_heads(const bias_nn_t *net, const int16_t h2[BIAS_NN_HIDDEN], float *std_out)
{
    int32_t acc[2];
    const unsigned n_heads = net->q_heads > 2u ? 2u : net->q_heads;
    q15_sums(h2, BIAS_NN_HIDDEN / 2u, net->q_wh, net->q_bh, n_heads, acc);
    if (std_out != NULL) {
        *std_out = n_heads > 1u ? bias_nn_std_of(net, (float)acc[1] * net->q_out_scale) : 0.0f;
    }
    return bias_nn_descale_output(net, (float)acc[0] * net->q_out_scale);
}

float bias_nn_predict_q15(const bias_nn_t *net, const float *features, float *std_out)
{
    int16_t x[BIAS_NN_MAX_IN + 1], h1[BIAS_NN_HIDDEN], h2[BIAS_NN_HIDDEN];
    int32_t acc[BIAS_NN_HIDDEN];
    const unsigned n_pairs = bias_nn_q15_inputs(net, features, x);
    q15_sums(x, n_pairs, net->q_w1, net->q_b1, BIAS_NN_HIDDEN, acc);
    q15_relu(acc, net->q_shift1, h1);
    q15_sums(h1, BIAS_NN_HIDDEN / 2u, net->q_w2, net->q_b2, BIAS_NN_HIDDEN, acc);
    q15_relu(acc, net->q_shift2, h2);
    return bias_nn_q15_heads(net, h2, std_out);
}
