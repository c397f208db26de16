/* Cortex-M4F kernel of the bias network (same maths as core/bias_nn.c's bias_nn_predict). */
#ifndef UWB_NN_M4_H
#define UWB_NN_M4_H

#include "bias_nn.h"

/* Scale, run, de-scale and clamp, like bias_nn_predict(); float32 FMA throughout. */
float nn_m4_predict(const bias_nn_t *net, const float *features, float *std_out);

/* The same with the hidden layers in C (blocked loop order and FMA, no hand-written loads). */
float nn_m4_predict_c(const bias_nn_t *net, const float *features, float *std_out);

/* One hidden layer in assembly (nn_m4_kernel.S): out[j] = relu(b[j] + sum_i x[i] w[i*50+j]). */
void dense_relu_m4(const float *x, unsigned n_in, const float *w, const float *b, float *out);

/* A q15 network (bias_nn.h, q_heads > 0): the hidden layers with SMLAD (nn_m4_q15.S), the same integers
 * as the core's bias_nn_predict_q15. */
float nn_m4_predict_q15(const bias_nn_t *net, const float *features, float *std_out);

/* nn_m4_q15.S: a q15 hidden layer of 50 outputs (w the layer's block-major table, bias_nn.h), dense over
 * n_pairs input pairs, or over the listed pairs only ((x pair word, 20 k) per pair k with a nonzero
 * input, ended by a zero word; 50 inputs); the two heads' sums added to acc2 (the biases on entry). */
void q15_dense_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, const int32_t *b, int16_t *out,
                  unsigned shift);
void q15_sparse_m4(const uint32_t *list, const int16_t *w, const int32_t *b, int16_t *out, unsigned shift);
void q15_heads2_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, int32_t acc2[2]);
/* The first head (the bias) alone of a two-head table; n_pairs a multiple of 5. */
void q15_head0_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, int32_t *acc);

/* The core's portable version, still linked under this name when the build wraps
 * bias_nn_predict (-Wl,--wrap=bias_nn_predict). */
float __real_bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out);
float __wrap_bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out);

#endif
