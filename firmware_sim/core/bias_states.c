/* Per-anchor Gauss-Markov bias states (bias_states.h); harness/twin/bias_states.py is the twin. */
#include "bias_states.h"

#include <math.h>
#include <string.h>

#include "time_ms.h"
#include "trig.h"

void bias_states_reset(bias_states_t *s)
{
    memset(s, 0, sizeof *s);
}

/* b <- a b, var <- a^2 var + std^2 (1 - a^2), a = exp(-dt / tau): the exact discretisation. */
static void propagate(bias_states_t *s, uint64_t t_us, uint8_t i)
{
    const float q = BIAS_ST_STD * BIAS_ST_STD;
    float a;
    if (!(s->known & (1u << i))) {
        s->b[i] = 0.0f;
        s->var[i] = q;
        s->known = (uint16_t)(s->known | (1u << i));
    } else if (t_us > s->t_us[i]) {
        a = trig_expf(-uwb_u64_to_float(t_us - s->t_us[i]) * 1e-6f / BIAS_ST_TAU_S);
        s->b[i] *= a;
        s->var[i] = a * a * s->var[i] + q * (1.0f - a * a);
    }
    s->t_us[i] = t_us;
}

void bias_states_predict(bias_states_t *s, uint64_t t_us, uint8_t a, uint8_t b, float *bias, float *var)
{
    propagate(s, t_us, a);
    if (a == b) {
        *bias = s->b[a];
        *var = s->var[a];
        return;
    }
    propagate(s, t_us, b);
    *bias = s->b[b] - s->b[a];
    *var = s->var[a] + s->var[b];
}

/* State i with measurement coefficient h (+1 or -1): K = var h / S. */
static void update_one(bias_states_t *s, uint8_t i, float h, float y, float S)
{
    const float k = s->var[i] * h / S;
    s->b[i] += k * y;
    s->var[i] *= 1.0f - k * h;
}

void bias_states_update(bias_states_t *s, uint8_t a, uint8_t b, float y, float S)
{
    if (!(S > 0.0f) || !isfinite(y)) {
        return;
    }
    if (a == b) {
        update_one(s, a, 1.0f, y, S);
        return;
    }
    update_one(s, a, -1.0f, y, S);
    update_one(s, b, 1.0f, y, S);
}
