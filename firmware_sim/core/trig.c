#include "trig.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

/* pi/2 = PIO2_1 + PIO2_2 + PIO2_3 (+ 5.7e-18): the first two have 12 significant bits, so k PIO2_1 and
 * k PIO2_2 are exact for |k| < 2^12 */
#define PIO2_1 1.57080078125f
#define PIO2_2 -4.45358455181e-06f
#define PIO2_3 -8.70551575272e-10f
#define TWO_OVER_PI 0.636619772f
#define SMALL_LIMIT 6000.0f
#define PIO2_2M62 3.40612167487e-19f   /* pi/2 2^-62 */
#define PIO4_BITS 0x3F490FDBu          /* |x| below this (pi/4 in float): no reduction */
#define NONFINITE_BITS 0x7F800000u

/* Bits of 2/pi after 16 zero bits: table bit t (from the top of word 0) is 2/pi's bit of weight 2^(15 - t). */
static const uint32_t two_over_pi_bits[7] = {0x0000A2F9u, 0x836E4E44u, 0x1529FC27u, 0x57D1F534u,
                                             0xDDC0DB62u, 0x95993C43u, 0x9041FE51u};

/* |x| >= SMALL_LIMIT, finite: x = m 2^e; x 2/pi mod 4 from m times the 64 bits of 2/pi from weight
 * 2^(1 - e) (the bits above give multiples of 4): an 88-bit product in units of 2^-62. */
static float reduce_large(uint32_t u, int *q)
{
    const int e = (int)((u >> 23) & 0xFFu) - 150;
    const uint64_t m = (u & 0x7FFFFFu) | 0x800000u;
    const unsigned t = (unsigned)(e + 14), k = t >> 5, sh = t & 31u;
    uint64_t w = ((uint64_t)two_over_pi_bits[k] << 32) | two_over_pi_bits[k + 1];
    uint64_t a0, a1, lo, hi, mid, frac;
    if (sh != 0) {
        w = (w << sh) | (two_over_pi_bits[k + 2] >> (32 - sh));
    }
    a0 = m * (uint32_t)w;   /* m < 2^24: m w = m w1 2^32 + m w0 */
    a1 = m * (w >> 32);
    mid = (a0 >> 32) + a1;
    lo = (mid << 32) | (uint32_t)a0;
    hi = mid >> 32;
    *q = (int)(((hi << 2) | (lo >> 62)) & 3u);
    frac = lo & 0x3FFFFFFFFFFFFFFFull;
    if (frac >= 0x2000000000000000ull) {   /* nearest quadrant: the fraction in [-1/2, 1/2) */
        ++*q;
        return (float)((int64_t)frac - 0x4000000000000000ll) * PIO2_2M62;
    }
    return (float)(int64_t)frac * PIO2_2M62;
}

/* x = (q + r / (pi/2)) pi/2 with |r| <= pi/4 (a hair more for huge x): returns r, *q in 0..3. */
static float reduce(float x, int *q)
{
    uint32_t u;
    float r;
    memcpy(&u, &x, sizeof u);
    if ((u & 0x7FFFFFFFu) < PIO4_BITS) {   /* |x| < pi/4: already reduced */
        *q = 0;
        return x;
    }
    if ((u & 0x7FFFFFFFu) < 0x45BB8000u) {   /* |x| < SMALL_LIMIT */
        const int k = (int)(x * TWO_OVER_PI + (x < 0.0f ? -0.5f : 0.5f));
        const float kf = (float)k;
        *q = k & 3;
        return ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    }
    r = reduce_large(u & 0x7FFFFFFFu, q);
    if (u >> 31) {
        *q = -*q;
        r = -r;
    }
    *q &= 3;
    return r;
}

static float sin_poly(float r)
{
    const float z = r * r;
    if (z == 0.0f) {
        return r;   /* keeps the sign of -0 */
    }
    return r + r * z * (-1.0f / 6.0f + z * (1.0f / 120.0f + z * (-1.0f / 5040.0f + z * (1.0f / 362880.0f))));
}

static float cos_poly(float r)
{
    /* 1 - z/2 rounded, and what that rounding lost added back with the higher terms */
    const float z = r * r, hz = 0.5f * z, w = 1.0f - hz;
    return w + (((1.0f - w) - hz) +
                z * z * (1.0f / 24.0f + z * (-1.0f / 720.0f + z * (1.0f / 40320.0f + z * (-1.0f / 3628800.0f)))));
}

/* sin(x + q pi/2) from r = the reduced x */
static float sin_quadrant(float r, int q)
{
    const float s = (q & 1) ? cos_poly(r) : sin_poly(r);
    return (q & 2) ? -s : s;
}

static uint32_t abs_bits(float x)
{
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    return u & 0x7FFFFFFFu;
}

float trig_sinf(float x)
{
    int q;
    float r;
    if (abs_bits(x) < PIO4_BITS) {
        return sin_poly(x);   /* the EKF's half rotation angles */
    }
    if (abs_bits(x) >= NONFINITE_BITS) {
        return x - x;
    }
    r = reduce(x, &q);
    return sin_quadrant(r, q);
}

float trig_cosf(float x)
{
    int q;
    float r;
    if (abs_bits(x) < PIO4_BITS) {
        return cos_poly(x);
    }
    if (abs_bits(x) >= NONFINITE_BITS) {
        return x - x;
    }
    r = reduce(x, &q);
    return sin_quadrant(r, q + 1);
}

float trig_tanf(float x)
{
    int q;
    float r;
    if (abs_bits(x) >= NONFINITE_BITS) {
        return x - x;
    }
    r = reduce(x, &q);
    return sin_quadrant(r, q) / sin_quadrant(r, q + 1);
}

/* e^x: x = k ln2 + r, |r| <= ln2/2 (k rounded by adding 1.5 2^23; ln2 in two parts: k ln2_hi is exact for
 * |k| <= 256), e^r by its Taylor polynomial to r^7 (truncation 5e-9 relative), times 2^k (for the extreme k
 * in two factors, each a normal float, so over- and underflow round as one multiplication would). Below
 * |x| = 0.34 k is 0 and r = x: the reduction is skipped (the bias states' decay always), the same number. */
float trig_expf(float x)
{
    const float shift = 12582912.0f;
    float r = x, p, s1, s2;
    uint32_t b1, b2;
    int32_t k = 0;
    if (!(fabsf(x) < 0.34f)) {
        float kf;
        uint32_t kb;
        if (!(x > -104.0f)) {
            return x != x ? x : 0.0f; /* e^-104 is below half the least subnormal */
        }
        if (x > 89.0f) {
            return INFINITY;
        }
        kf = x * 1.44269504f + shift;
        memcpy(&kb, &kf, sizeof kb);
        k = (int32_t)(kb - 0x4b400000u);
        kf -= shift;
        r = (x - kf * 0.693145752f) - kf * 1.42860677e-06f;
    }
    p = 1.98412698e-04f;
    p = p * r + 1.38888889e-03f;
    p = p * r + 8.33333333e-03f;
    p = p * r + 4.16666667e-02f;
    p = p * r + 1.66666667e-01f;
    p = p * r + 0.5f;
    p = p * r + 1.0f;
    p = p * r + 1.0f;
    if (k == 0) {
        return p;
    }
    if (k > -127 && k < 128) {
        b1 = (uint32_t)(k + 127) << 23;
        memcpy(&s1, &b1, sizeof s1);
        return p * s1;
    }
    b1 = (uint32_t)(k / 2 + 127) << 23;
    b2 = (uint32_t)(k - k / 2 + 127) << 23;
    memcpy(&s1, &b1, sizeof s1);
    memcpy(&s2, &b2, sizeof s2);
    return p * s1 * s2;
}
