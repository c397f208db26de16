/* The bias network's forward pass tuned for the Cortex-M4F (FPv4-SP: 32 single registers, VFMA).
 *
 * What changes against the portable loop (one output at a time, one load per MAC):
 *  - loop order: outputs are computed in blocks of 10 kept in 10 FPU registers; the input loop runs
 *    inside the block, so each input x[i] is loaded once per block and feeds 10 FMAs whose weights
 *    are contiguous in memory (w is stored input-major, n_in x 50);
 *  - unrolling: the 10 accumulators are explicit, and the input loop is unrolled by 2;
 *  - float32 FMA (vfma.f32) for every multiply-add, independent accumulators so consecutive FMAs
 *    never wait on each other;
 *  - ReLU applied once when a block is stored.
 * Two implementations of the hidden layers: dense_relu() below in C (GCC still issues one VLDR per
 * weight), and dense_relu_m4() in nn_m4_kernel.S, which loads the 10 weights of a block with one
 * VLDM. nn_m4_predict() uses the assembly; nn_m4_predict_c() is kept for the benchmark ladder.
 * The summation order per output is the same as a sequential dot product (bias first, then inputs
 * in order), so results stay within float32 rounding of the reference.
 *
 * Linked in place of bias_nn_predict with -Wl,--wrap=bias_nn_predict (see Makefile): the core's
 * sources stay unchanged and its version remains available as __real_bias_nn_predict. */
#include "nn_m4.h"

#define H BIAS_NN_HIDDEN

typedef char check_hidden_is_multiple_of_10[(H % 10 == 0) ? 1 : -1];

#define FMA(acc, w, x) ((acc) = __builtin_fmaf((w), (x), (acc)))
#define FMA10(wp, x)                                                                                           \
    do {                                                                                                       \
        FMA(a0, (wp)[0], (x));                                                                                 \
        FMA(a1, (wp)[1], (x));                                                                                 \
        FMA(a2, (wp)[2], (x));                                                                                 \
        FMA(a3, (wp)[3], (x));                                                                                 \
        FMA(a4, (wp)[4], (x));                                                                                 \
        FMA(a5, (wp)[5], (x));                                                                                 \
        FMA(a6, (wp)[6], (x));                                                                                 \
        FMA(a7, (wp)[7], (x));                                                                                 \
        FMA(a8, (wp)[8], (x));                                                                                 \
        FMA(a9, (wp)[9], (x));                                                                                 \
    } while (0)

static inline float relu(float v) { return v > 0.0f ? v : 0.0f; }

/* out[j] = relu(b[j] + sum_i x[i] w[i][j]) for j < 50; w is n_in x 50, input-major. */
static void dense_relu(const float *x, unsigned n_in, const float *w, const float *b, float *out)
{
    unsigned j0;
    for (j0 = 0; j0 < H; j0 += 10u) {
        const float *wp = w + j0;
        const float *xp = x;
        float a0 = b[j0 + 0u], a1 = b[j0 + 1u], a2 = b[j0 + 2u], a3 = b[j0 + 3u], a4 = b[j0 + 4u];
        float a5 = b[j0 + 5u], a6 = b[j0 + 6u], a7 = b[j0 + 7u], a8 = b[j0 + 8u], a9 = b[j0 + 9u];
        unsigned i;
        for (i = n_in / 2u; i != 0u; i--) {
            const float x0 = xp[0], x1 = xp[1];
            FMA10(wp, x0);
            FMA10(wp + H, x1);
            wp += 2u * H;
            xp += 2;
        }
        if ((n_in & 1u) != 0u) {
            const float x0 = xp[0];
            FMA10(wp, x0);
        }
        out[j0 + 0u] = relu(a0);
        out[j0 + 1u] = relu(a1);
        out[j0 + 2u] = relu(a2);
        out[j0 + 3u] = relu(a3);
        out[j0 + 4u] = relu(a4);
        out[j0 + 5u] = relu(a5);
        out[j0 + 6u] = relu(a6);
        out[j0 + 7u] = relu(a7);
        out[j0 + 8u] = relu(a8);
        out[j0 + 9u] = relu(a9);
    }
}

/* b + sum_j h[j] w[j], summed sequentially like the reference. */
static float dense_out(const float *h, const float *w, float b)
{
    float acc = b;
    unsigned j;
    for (j = 0; j < H; j += 5u) {
        FMA(acc, w[j + 0u], h[j + 0u]);
        FMA(acc, w[j + 1u], h[j + 1u]);
        FMA(acc, w[j + 2u], h[j + 2u]);
        FMA(acc, w[j + 3u], h[j + 3u]);
        FMA(acc, w[j + 4u], h[j + 4u]);
    }
    return acc;
}

typedef void (*layer_fn)(const float *x, unsigned n_in, const float *w, const float *b, float *out);

static inline float predict_with(const bias_nn_t *net, const float *features, float *std_out, layer_fn layer)
{
    float x[BIAS_NN_MAX_IN];
    float h1[H], h2[H];
    float y;
    const unsigned n_in = bias_nn_scale_inputs(net, features, x);

    layer(x, n_in, net->w1, net->b1, h1);
    layer(h1, H, net->w2, net->b2, h2);
    y = dense_out(h2, net->w3, net->b3);
    if (std_out != (float *)0) {
        *std_out = bias_nn_std_head(net, h2); /* 50 MACs and one expf: the core's C is enough */
    }
    return bias_nn_descale_output(net, y);
}

float nn_m4_predict(const bias_nn_t *net, const float *features, float *std_out)
{
    return predict_with(net, features, std_out, dense_relu_m4);
}

typedef char check_sparse_stride_is_500_bytes[(H == 50) ? 1 : -1]; /* nn_m4_q15.S: SPARSE_STRIDE; 25 pairs = 5 x 5 */

/* Beyond this many nonzero pairs of 25 the dense loop is cheaper (10 blocks x ~9.5 instructions per listed
 * pair against ~70 per pair dense): the worst case stays the dense kernel's. */
#define SPARSE_MAX_PAIRS 18u

/* The list q15_sparse_m4 reads: (pair word, 20 k) for each pair k of h with a nonzero unit, then a zero word.
 * h is read as 25 words (two int16 each: the layer's pairs). Returns the number of entries. */
typedef char check_odd_word_count[(H / 2) % 2 == 1 ? 1 : -1]; /* nonzero_pairs: 12 double words + 1 */

static inline uint32_t *list_pair(uint32_t *e, uint32_t word, unsigned k)
{
    if (word != 0u) {
        e[0] = word;
        e[1] = 20u * k;
        e += 2;
    }
    return e;
}

static unsigned nonzero_pairs(const uint32_t h[H / 2], uint32_t list[H + 1])
{
    unsigned k;
    uint32_t *e = list;
    for (k = 0; k + 1u < H / 2u; k += 2u) { /* two words at a time: most are both 0 (ReLU) */
        if ((h[k] | h[k + 1u]) != 0u) {
            e = list_pair(e, h[k], k);
            e = list_pair(e, h[k + 1u], k + 1u);
        }
    }
    e = list_pair(e, h[H / 2u - 1u], H / 2u - 1u);
    e[0] = 0u;
    return (unsigned)(e - list) / 2u;
}

float nn_m4_predict_q15(const bias_nn_t *net, const float *features, float *std_out)
{
    int16_t x[BIAS_NN_MAX_IN + 1], h2[H];
    uint32_t h1[H / 2], list[H + 1]; /* h1: 50 int16 written by the kernel, read as 25 pairs */
    const unsigned n_pairs = bias_nn_q15_inputs(net, features, x);
    q15_dense_m4(x, n_pairs, net->q_w1, net->q_b1, (int16_t *)h1, net->q_shift1);
    if (nonzero_pairs(h1, list) <= SPARSE_MAX_PAIRS) {
        q15_sparse_m4(list, net->q_w2, net->q_b2, h2, net->q_shift2);
    } else {
        q15_dense_m4((const int16_t *)h1, H / 2u, net->q_w2, net->q_b2, h2, net->q_shift2);
    }
    if (net->q_heads == 2u) {
        int32_t acc[2];
        acc[0] = net->q_bh[0];
        acc[1] = net->q_bh[1];
        if (std_out != (float *)0) {
            q15_heads2_m4(h2, H / 2u, net->q_wh, acc);
            *std_out = bias_nn_std_of(net, (float)acc[1] * net->q_out_scale);
        } else {
            q15_head0_m4(h2, H / 2u, net->q_wh, acc); /* the std is not wanted (estimator.c) */
        }
        return bias_nn_descale_output(net, (float)acc[0] * net->q_out_scale);
    }
    return bias_nn_q15_heads(net, h2, std_out);
}

float nn_m4_predict_c(const bias_nn_t *net, const float *features, float *std_out)
{
    return predict_with(net, features, std_out, dense_relu);
}

float __wrap_bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out)
{
    if (net->q_heads > 0u) { /* a q15 network (bias_nn.h) */
        return nn_m4_predict_q15(net, features, std_out);
    }
    return nn_m4_predict(net, features, std_out);
}
