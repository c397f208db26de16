/* nn_eval: evaluate the compiled-in bias networks on feature vectors read from stdin.
 * Used by tests/unit/test_biasnet.py to compare C, PyTorch and numpy on the same exported header
 * (build with -DBIAS_MODEL_HEADER='"path/to/header.h"' to test any model).
 *
 * First output line: "H hash_hex layout_twr layout_tdoa".
 * Input lines: "twr f0 .. fn-1" or "tdoa f0 .. fn-1" (n = the network's input count).
 * Output: one line per input, the predicted bias and std (0 without a std head) with 9 significant
 * digits, or "E reason". */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bias_nn.h"

int main(void)
{
    char line[1024];
    const bias_model_t *m = &bias_model_compiled;
    printf("H %016" PRIx64 " %u %u\n", m->hash, m->twr ? (unsigned)m->twr->layout : 0u,
           m->tdoa ? (unsigned)m->tdoa->layout : 0u);
    while (fgets(line, sizeof line, stdin) != NULL) {
        float x[BIAS_NN_MAX_IN];
        const bias_nn_t *net;
        char *p = line, *end;
        int i;
        if (strncmp(p, "twr ", 4) == 0) {
            net = m->twr;
            p += 4;
        } else if (strncmp(p, "tdoa ", 5) == 0) {
            net = m->tdoa;
            p += 5;
        } else {
            printf("E unknown kind\n");
            continue;
        }
        if (net == NULL) {
            printf("E no network\n");
            continue;
        }
        for (i = 0; i < (int)net->n_in; i++) {
            x[i] = strtof(p, &end);
            if (end == p) {
                break;
            }
            p = end;
        }
        if (i != (int)net->n_in) {
            printf("E expected %u features\n", (unsigned)net->n_in);
            continue;
        }
        {
            float std = -1.0f;
            const float bias = bias_nn_predict(net, x, &std);
            printf("%.9g %.9g\n", (double)bias, (double)std);
        }
    }
    return 0;
}
