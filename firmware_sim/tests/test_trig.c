/* trig.h's sin, cos, tan against the host's double sin, cos, tan (and, for the record, its float libm):
 * a dense grid over the angles the firmware passes, random arguments up to the reduction's switch at
 * 6,000 rad and beyond it up to FLT_MAX, and the special values. Error in float ulps of the result
 * (the ulp of |y| >= 2^-8; absolute error in units of 2^-32 closer to a zero). */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "trig.h"
#include "unit.h"

static uint64_t rng = 0x2545F4914F6CDD1Dull;

static uint32_t next(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

typedef struct {
    double max_ulp, max_libm_ulp;
} err_t;

/* error of y against the double truth t: ulps of t's float binade, or 2^-32 units near a zero */
static double err_ulp(float y, double t)
{
    const double at = fabs(t);
    const double ulp = at >= 0x1p-8 ? ldexp(1.0, ilogb(at) - 23) : 0x1p-32;
    return fabs((double)y - t) / ulp;
}

static void check_one(float x, err_t *e)
{
    const double xd = (double)x;
    double u;
    u = fmax(err_ulp(trig_sinf(x), sin(xd)), err_ulp(trig_cosf(x), cos(xd)));
    e->max_ulp = fmax(e->max_ulp, u);
    u = fmax(err_ulp(trig_sinf(x), (double)sinf(x)), err_ulp(trig_cosf(x), (double)cosf(x)));
    e->max_libm_ulp = fmax(e->max_libm_ulp, u);
}

static float from_bits(uint32_t b)
{
    float f;
    memcpy(&f, &b, sizeof f);
    return f;
}

static void test_grid_and_random(void)
{
    err_t small = {0, 0}, mid = {0, 0}, large = {0, 0};
    int i;
    for (i = -200000; i <= 200000; i++) {   /* [-8, 8] rad: rotation half-angles, yaw, tilt */
        check_one((float)i * 4e-5f, &small);
    }
    for (i = 0; i < 200000; i++) {
        check_one(((float)next() / 4294967296.0f - 0.5f) * 12000.0f, &mid);
    }
    for (i = 0; i < 200000; i++) {   /* every binade from 6,000 (2^12.55) to FLT_MAX, either sign */
        const uint32_t b = ((140u + next() % 115u) << 23) | (next() & 0x807FFFFFu);
        if (fabsf(from_bits(b)) >= 6000.0f && isfinite(from_bits(b))) {
            check_one(from_bits(b), &large);
        }
    }
    printf("    max error vs double, float ulps: |x| <= 8: %.2f, |x| < 6000: %.2f, beyond: %.2f\n",
           small.max_ulp, mid.max_ulp, large.max_ulp);
    printf("    max difference from the host's sinf/cosf, float ulps: %.2f / %.2f / %.2f\n",
           small.max_libm_ulp, mid.max_libm_ulp, large.max_libm_ulp);
    CHECK(small.max_ulp <= 2.5);
    CHECK(mid.max_ulp <= 2.5);
    CHECK(large.max_ulp <= 2.5);
}

/* trig_expf over every float step of 7e-4 where e^x is a normal float, against exp in double */
static void test_expf(void)
{
    double worst = 0.0;
    float x;
    for (x = -87.3f; x < 88.7f; x += 7.31e-4f) {
        const double t = exp((double)x);
        worst = fmax(worst, fabs((double)trig_expf(x) - t) / ldexp(1.0, ilogb(t) - 23));
    }
    printf("    max error of trig_expf, float ulps: %.2f\n", worst);
    CHECK(worst <= 1.25);
    CHECK(trig_expf(0.0f) == 1.0f && trig_expf(-200.0f) == 0.0f && isinf(trig_expf(100.0f)));
    CHECK(isnan(trig_expf(NAN)) && trig_expf(-INFINITY) == 0.0f && isinf(trig_expf(INFINITY)));
}

static void test_special_values(void)
{
    CHECK(trig_sinf(0.0f) == 0.0f && trig_cosf(0.0f) == 1.0f && trig_tanf(0.0f) == 0.0f);
    CHECK(signbit(trig_sinf(-0.0f)));
    CHECK(trig_sinf(1e-30f) == 1e-30f && trig_cosf(1e-30f) == 1.0f);
    CHECK(isnan(trig_sinf(INFINITY)) && isnan(trig_cosf(-INFINITY)) && isnan(trig_tanf(NAN)));
    CHECK(fabs(trig_tanf(0.6f) - tan(0.6)) <= 2.0 * ldexp(1.0, ilogb(tan(0.6)) - 23));
    CHECK(fabs(trig_sinf(FLT_MAX) - sin((double)FLT_MAX)) <= 1e-7);
}

int main(void)
{
    RUN(test_grid_and_random);
    RUN(test_special_values);
    RUN(test_expf);
    return UNIT_DONE();
}
