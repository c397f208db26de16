/* The bias network: 2 hidden layers x 50 ReLU -> 1 linear output, float32, no allocation.
 *
 * Storage order (written by harness/biasnet/export.py, read the same way by stm32/nn_m4.c):
 *   w1[i * 50 + j]  weight from scaled input i to hidden-1 unit j   (n_in x 50, input-major)
 *   w2[i * 50 + j]  weight from hidden-1 unit i to hidden-2 unit j  (50 x 50, input-major)
 *   w3[j]           weight from hidden-2 unit j to the output
 * Each unit sums its bias first, then its inputs in order: the M4 kernel keeps that order so its
 * results stay within float32 rounding of this reference.
 * Input scaling x' = (x - in_min) / (in_max - in_min); output y = y' (out_max - out_min) + out_min,
 * clamped to [out_min, out_max] so a network queried outside its training range cannot produce an
 * arbitrarily large correction. */
#include "bias_nn.h"

#include <math.h>

#include "trig.h"

/* The compiled-in model: BIAS_MODEL_HEADER (a header written by `uwb-hil export-c`) or the shipped
 * default. The header defines BIAS_MODEL_TWR, BIAS_MODEL_TDOA (pointers or NULL) and BIAS_MODEL_HASH. */
#ifdef BIAS_MODEL_HEADER
#include BIAS_MODEL_HEADER
#else
#include "bias_model_default.h"
#endif

#ifndef NULL
#define NULL ((void *)0)
#endif

const bias_model_t bias_model_compiled = {BIAS_MODEL_TWR, BIAS_MODEL_TDOA, BIAS_MODEL_HASH};

/* Number of inputs of a layout (0 for unknown). */
static uint8_t bias_nn_layout_inputs(uint8_t layout)
{
    switch (layout) {
    case BIAS_LAYOUT_TWR_POSE:
        return 6u;
    case BIAS_LAYOUT_TDOA_POSE:
        return 9u;
    case BIAS_LAYOUT_TWR_POS:
        return 3u;
    case BIAS_LAYOUT_TDOA_POS:
        return 6u;
    default:
        return 0u;
    }
}

uint8_t bias_nn_features(uint8_t layout, const float tag[3], const float rpy[3], const float anchor_a[3],
                         const float anchor_b[3], float out[BIAS_NN_MAX_IN])
{
    uint8_t n = 0u;
    int k;
    const int tdoa = layout == BIAS_LAYOUT_TDOA_POSE || layout == BIAS_LAYOUT_TDOA_POS;
    const int angles = layout == BIAS_LAYOUT_TWR_POSE || layout == BIAS_LAYOUT_TDOA_POSE;

    if (bias_nn_layout_inputs(layout) == 0u || (tdoa && anchor_b == NULL)) {
        return 0u;
    }
    const float t[3] = {tag[0], tag[1], tag[2]}; /* read once: the stores to out could alias it */
    for (k = 0; k < 3; k++) {
        out[n++] = anchor_a[k] - t[k];
    }
    if (tdoa) {
        for (k = 0; k < 3; k++) {
            out[n++] = anchor_b[k] - t[k];
        }
    }
    if (angles) {
        for (k = 0; k < 3; k++) {
            out[n++] = rpy[k];
        }
    }
    return n;
}

/* out[j] = relu(b[j] + sum_i x[i] w[i * 50 + j]). The input loop is outside: each pass reads one
 * contiguous weight row and updates all 50 sums (the compiler vectorises it), while every sum still
 * adds its terms in input order, bias first: the same rounding as a sequential dot product. */
static void dense_relu(const float *x, uint8_t n_in, const float *restrict w, const float *b, float *restrict out)
{
    int i, j;
    for (j = 0; j < BIAS_NN_HIDDEN; j++) {
        out[j] = b[j];
    }
    for (i = 0; i < (int)n_in; i++) {
        const float xi = x[i];
        const float *row = w + i * BIAS_NN_HIDDEN;
        for (j = 0; j < BIAS_NN_HIDDEN; j++) {
            out[j] += xi * row[j];
        }
    }
    for (j = 0; j < BIAS_NN_HIDDEN; j++) {
        out[j] = out[j] > 0.0f ? out[j] : 0.0f;
    }
}

float bias_nn_ood_excess(const bias_nn_t *net, const float *features)
{
    float worst = 0.0f;
    int i;
    const int n_in = net->n_in <= BIAS_NN_MAX_IN ? (int)net->n_in : BIAS_NN_MAX_IN;
    for (i = 0; i < n_in; i++) {
        /* Inside [in_min, in_max] (the usual case) neither excess below can be > 0: no divisions. */
        if (features[i] >= net->in_min[i] && features[i] <= net->in_max[i]) {
            continue;
        }
        const float width = net->in_max[i] - net->in_min[i];
        const float below = (net->in_min[i] - features[i]) / width;
        const float above = (features[i] - net->in_max[i]) / width;
        if (below > worst) {
            worst = below;
        }
        if (above > worst) {
            worst = above;
        }
        if (features[i] != features[i]) { /* NaN: as far out as it gets */
            worst = 1e30f;
        }
    }
    return worst;
}

float bias_nn_ood_fade(float excess)
{
    const float f = 1.0f - excess / BIAS_NN_OOD_MARGIN;
    if (!(f > 0.0f)) {
        return 0.0f;
    }
    return f < 1.0f ? f : 1.0f;
}

float bias_nn_std_head(const bias_nn_t *net, const float h2[BIAS_NN_HIDDEN])
{
    float s = net->b3s;
    int i;
    if (net->w3s == NULL) {
        return 0.0f;
    }
    for (i = 0; i < BIAS_NN_HIDDEN; i++) {
        s += h2[i] * net->w3s[i];
    }
    return bias_nn_std_of(net, s);
}

float bias_nn_std_of(const bias_nn_t *net, float s)
{
    float std = trig_expf(s);
    /* NaN fails both comparisons' "inside" side and ends at std_max: trust least when unsure */
    if (!(std <= net->std_max)) {
        std = net->std_max;
    }
    if (std < net->std_min) {
        std = net->std_min;
    }
    return std;
}

float bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out)
{
    float x[BIAS_NN_MAX_IN], h1[BIAS_NN_HIDDEN], h2[BIAS_NN_HIDDEN];
    float y;
    int i;
    uint8_t n_in;
    if (net->q_heads > 0u) {
        return bias_nn_predict_q15(net, features, std_out);
    }
    n_in = (uint8_t)bias_nn_scale_inputs(net, features, x);

    dense_relu(x, n_in, net->w1, net->b1, h1);
    dense_relu(h1, (uint8_t)BIAS_NN_HIDDEN, net->w2, net->b2, h2);
    y = net->b3;
    for (i = 0; i < BIAS_NN_HIDDEN; i++) {
        y += h2[i] * net->w3[i];
    }
    if (std_out != NULL) {
        *std_out = bias_nn_std_head(net, h2);
    }
    return bias_nn_descale_output(net, y);
}
