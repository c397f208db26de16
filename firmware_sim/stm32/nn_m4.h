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

/* The core's portable version, still linked under this name when the build wraps
 * bias_nn_predict (-Wl,--wrap=bias_nn_predict). */
float __real_bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out);
float __wrap_bias_nn_predict(const bias_nn_t *net, const float *features, float *std_out);

#endif
