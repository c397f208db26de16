/* Unit tests of the per-anchor bias states (core/bias_states.c). */
#include <math.h>

#include "bias_states.h"
#include "unit.h"

static void test_start_and_decay(void)
{
    bias_states_t s;
    float b, v;
    const float q = BIAS_ST_STD * BIAS_ST_STD;
    const uint64_t tau_us = (uint64_t)(BIAS_ST_TAU_S * 1e6f);
    bias_states_reset(&s);
    bias_states_predict(&s, 1000u, 3, 3, &b, &v); /* first measurement: 0 with the stationary variance */
    CHECK_NEAR(b, 0.0f, 0.0f);
    CHECK_NEAR(v, q, 1e-9);
    bias_states_update(&s, 3, 3, 0.2f, 2.0f * q); /* K = 1/2 */
    CHECK_NEAR(s.b[3], 0.1f, 1e-7);
    CHECK_NEAR(s.var[3], 0.5f * q, 1e-9);
    bias_states_predict(&s, 1000u + tau_us, 3, 3, &b, &v); /* one correlation time later */
    CHECK_NEAR(b, 0.1f * expf(-1.0f), 1e-6);
    CHECK_NEAR(v, q - 0.5f * q * expf(-2.0f), 1e-7);
    bias_states_predict(&s, 1000u + 100u * tau_us, 3, 3, &b, &v); /* forgotten */
    CHECK_NEAR(b, 0.0f, 1e-9);
    CHECK_NEAR(v, q, 1e-7);
}

static void test_tdoa_signs(void)
{
    bias_states_t s;
    float b, v;
    const float q = BIAS_ST_STD * BIAS_ST_STD;
    bias_states_reset(&s);
    bias_states_predict(&s, 5u, 1, 2, &b, &v); /* d(2) - d(1): beta_2 - beta_1 */
    CHECK_NEAR(v, 2.0f * q, 1e-9);
    bias_states_update(&s, 1, 2, 0.1f, 4.0f * q); /* each takes var / S = 1/4 of y, with its sign */
    CHECK_NEAR(s.b[1], -0.025f, 1e-7);
    CHECK_NEAR(s.b[2], 0.025f, 1e-7);
    CHECK_NEAR(s.var[1], 0.75f * q, 1e-9);
    bias_states_predict(&s, 5u, 1, 2, &b, &v); /* same time: no decay */
    CHECK_NEAR(b, 0.05f, 1e-7);
    CHECK_NEAR(v, 1.5f * q, 1e-9);
    CHECK(s.known == ((1u << 1) | (1u << 2)));
}

static void test_bad_input_changes_nothing(void)
{
    bias_states_t s;
    float b, v;
    bias_states_reset(&s);
    bias_states_predict(&s, 5u, 0, 4, &b, &v);
    bias_states_update(&s, 0, 4, NAN, 1.0f);
    bias_states_update(&s, 0, 4, 0.3f, 0.0f);
    bias_states_update(&s, 0, 4, 0.3f, NAN);
    CHECK(s.b[0] == 0.0f && s.b[4] == 0.0f);
    CHECK_NEAR(s.var[4], BIAS_ST_STD * BIAS_ST_STD, 1e-9);
}

int main(void)
{
    RUN(test_start_and_decay);
    RUN(test_tdoa_signs);
    RUN(test_bad_input_changes_nothing);
    return UNIT_DONE();
}
