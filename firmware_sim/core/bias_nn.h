/* The bias network: 2 hidden layers x 50 ReLU -> 1 linear output (the bias), float32, const weights
 * (flash); optionally a second linear head on the same hidden layer: the log of the standard deviation
 * of the corrected error, bounded to [std_min, std_max] (harness/biasnet/uncertainty.py). */
#ifndef UWB_BIAS_NN_H
#define UWB_BIAS_NN_H

#include <stdint.h>

#define BIAS_NN_HIDDEN 50
#define BIAS_NN_Q15_BLOCK(n_out) ((n_out) % 5u == 0u ? 5u : (n_out)) /* outputs per block (q15 layout) */
#define BIAS_NN_MAX_IN 9

/* Input layouts (protocol enum `layout`). dp = anchor - tag position, world frame [m]. */
enum {
    BIAS_LAYOUT_NONE = 0,
    BIAS_LAYOUT_TWR_POSE = 1,  /* [dp(3), roll, pitch, yaw] */
    BIAS_LAYOUT_TDOA_POSE = 2, /* [dp_A(3), dp_B(3), roll, pitch, yaw] */
    BIAS_LAYOUT_TWR_POS = 3,   /* [dp(3)] */
    BIAS_LAYOUT_TDOA_POS = 4   /* [dp_A(3), dp_B(3)] */
};

/* One network. Weight storage order is documented in bias_nn.c and written by
 * harness/biasnet/export.py; all pointers refer to const tables. */
typedef struct {
    uint8_t layout;
    uint8_t n_in;
    const float *w1;     /* n_in x 50 */
    const float *b1;     /* 50 */
    const float *w2;     /* 50 x 50 */
    const float *b2;     /* 50 */
    const float *w3;     /* 50 */
    float b3;
    const float *in_min; /* n_in */
    const float *in_max; /* n_in */
    float out_min;
    float out_max;
    const float *w3s;    /* 50: std head (log std), or NULL: the network predicts no std */
    float b3s;
    float std_min;       /* bounds of the predicted std [m] */
    float std_max;
    /* The q15 form (harness/biasnet/q15.py), used when q_heads > 0 (the float tables w1..w3s are then
     * NULL): int16 weights and activations, int32 sums. Weights block-major for the M4's SMLAD: outputs
     * in blocks of B = BIAS_NN_Q15_BLOCK(n_out), inputs in pairs (n_in padded to even with zeros); output
     * j = b B + t, pair k: int16 q_w[((b n_pairs + k) B + t) 2 + h] = w[2k + h][j]. Heads: output 0 the
     * bias, 1 the log std. The exporter orders the first hidden layer's units so that units often 0
     * together share a pair (harness/biasnet/q15.py hidden_pair_order; the same outputs). */
    uint8_t q_heads;     /* 0: float32 network; 1: q15 with the bias head; 2: q15 with the bias and std heads */
    uint8_t q_shift1;    /* hidden-layer requantisation: activation = clamp(sum >> shift, 0, 32767) */
    uint8_t q_shift2;
    const int16_t *q_w1;
    const int32_t *q_b1; /* 50, the rounding half of q_shift1 included */
    const int16_t *q_w2;
    const int32_t *q_b2;
    const int16_t *q_wh;
    const int32_t *q_bh; /* q_heads */
    float q_out_scale;   /* head sum -> the float network's output unit (a power of two) */
} bias_nn_t;

/* The compiled-in model: one network per measurement kind (either may be NULL). */
typedef struct {
    const bias_nn_t *twr;
    const bias_nn_t *tdoa;
    uint64_t hash;       /* harness/biasnet/network.py: first 8 bytes of SHA-256, little-endian */
} bias_model_t;

/* Build the feature vector for `layout` from the estimated tag position, Euler angles
 * (roll, pitch, yaw [rad]) and the anchor positions (anchor_b unused for TWR layouts).
 * Returns the number of features written (0 for an unknown layout). */
uint8_t bias_nn_features(uint8_t layout, const float tag[3], const float rpy[3],
                         const float anchor_a[3], const float anchor_b[3], float out[BIAS_NN_MAX_IN]);

/* Scale, run, de-scale and clamp: the bias in metres (measured - true). If std_out is not NULL it
 * receives the predicted std of the corrected error [m], clamped to [std_min, std_max] (NaN -> std_max),
 * or 0 when the network has no std head. */
float bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out);

/* Out of the training range: a network is only trusted inside the box [in_min, in_max] it was trained
 * on. bias_nn_ood_excess() is the largest distance of any input beyond its range, in units of that
 * range's width (0 inside); the estimator fades the correction linearly to zero over
 * BIAS_NN_OOD_MARGIN of excess (and moves the std back to the configured one). */
#define BIAS_NN_OOD_MARGIN 0.1f
float bias_nn_ood_excess(const bias_nn_t *net, const float *features);

/* 1 inside the training range, falling linearly to 0 at BIAS_NN_OOD_MARGIN of excess (0 for NaN). */
float bias_nn_ood_fade(float excess);

/* The two ends of every kernel (bias_nn.c, the M4 kernels), inline so each kernel's instruction count is
 * its own: inputs min-max scaled as trained (returns n_in, at most BIAS_NN_MAX_IN), the linear output
 * de-scaled and clamped to [out_min, out_max]. */
static inline unsigned bias_nn_scale_inputs(const bias_nn_t *net, const float *features, float x[BIAS_NN_MAX_IN])
{
    unsigned i;
    const unsigned n_in = net->n_in <= BIAS_NN_MAX_IN ? net->n_in : (unsigned)BIAS_NN_MAX_IN;
    for (i = 0; i < n_in; i++) {
        x[i] = (features[i] - net->in_min[i]) / (net->in_max[i] - net->in_min[i]);
    }
    return n_in;
}

static inline float bias_nn_descale_output(const bias_nn_t *net, float y)
{
    y = y * (net->out_max - net->out_min) + net->out_min;
    if (y < net->out_min) {
        y = net->out_min;
    }
    if (y > net->out_max) {
        y = net->out_max;
    }
    return y;
}

/* The std head on a computed second hidden layer h2 (shared by bias_nn.c and the M4 kernel). */
float bias_nn_std_head(const bias_nn_t *net, const float h2[BIAS_NN_HIDDEN]);

/* The std of a log-std value s, clamped to [std_min, std_max] (NaN -> std_max). */
float bias_nn_std_of(const bias_nn_t *net, float s);

/* A q15 network (q_heads > 0): the bias (and the std when std_out != NULL), as bias_nn_predict. */
float bias_nn_predict_q15(const bias_nn_t *net, const float *features, float *std_out);
/* Its two ends (shared with the M4 kernel): the int16 inputs (padded to pairs; returns the number of
 * pairs), and the heads on the second hidden layer: the bias, the std into *std_out when not NULL. */
unsigned bias_nn_q15_inputs(const bias_nn_t *net, const float *features, int16_t x[BIAS_NN_MAX_IN + 1]);
float bias_nn_q15_heads(const bias_nn_t *net, const int16_t h2[BIAS_NN_HIDDEN], float *std_out);

/* The model the firmware is built with (firmware_sim/models/bias_model_default.h, or the
 * header named by -DBIAS_MODEL_HEADER). Defined in bias_nn.c. */
extern const bias_model_t bias_model_compiled;

#endif
