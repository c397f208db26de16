/* TWR from an antenna on a lever arm (ARCHITECTURE.md, pipeline step 1) and its row of the kinds table.
 * The state is the body origin p; the antenna sits at l = (lever_x, lever_y, lever_z) in the body frame, so
 * h(x) = |p + R l - a| and H = [(p + R l - a)^T / h, 0 ... 0] (the attitude part is left out, as the
 * other models': only position rows). With l = 0 it is the TWR model. */
#include <math.h>

#include "mm_twr.h"

static int model(const mm_input_t *in, float *h, float H[3])
{
    const float l[3] = {in->cfg->lever_x, in->cfg->lever_y, in->cfg->lever_z};
    float antenna[3];
    int i;
    for (i = 0; i < 3; i++) {
        antenna[i] = in->p[i] + in->R[i][0] * l[0] + in->R[i][1] * l[1] + in->R[i][2] * l[2];
    }
    return mm_twr(antenna, in->a, h, H);
}

const mm_kind_t mm_kind_twr_arm = {MM_KIND_TWR_ARM, 1, model, offsetof(estimator_config_t, std_twr),
                                   offsetof(estimator_config_t, chi2_twr), offsetof(estimator_config_t, a_max_twr),
                                   1.0f, MM_NO_NET, NULL, 0.0f};
