#include "tdoa_clock.h"

/* double(0.1) = 0x1999999999999A 2^-56, double(0.9) = 0x1CCCCCCCCCCCCD 2^-53 */
#define MANT_0_1 0x1999999999999Aull
#define MANT_0_9 0x1CCCCCCCCCCCCDull

static unsigned bitlen64(uint64_t v)
{
#if defined(__GNUC__)
    return v == 0 ? 0u : 64u - (unsigned)__builtin_clzll(v);   /* CLZ on the M4 */
#else
    unsigned n = 0, s;
    for (s = 32; s > 0; s >>= 1) {
        if (v >> s) {
            v >>= s;
            n += s;
        }
    }
    return n + (unsigned)v;
#endif
}

/* hi:lo = a b (64 x 64 -> 128 bits) */
static void mul64(uint64_t a, uint64_t b, uint64_t *hi, uint64_t *lo)
{
    const uint64_t a0 = (uint32_t)a, a1 = a >> 32, b0 = (uint32_t)b, b1 = b >> 32;
    const uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0;
    const uint64_t mid = (p00 >> 32) + (uint32_t)p01 + (uint32_t)p10;
    *lo = (mid << 32) | (uint32_t)p00;
    *hi = a1 * b1 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
}

/* hi:lo (< 2^116) rounded to 53 significant bits, to nearest, ties to even, as a double holds it:
 * m 2^p, m <= 2^53; returns m, *p (0 when nothing was rounded off). */
static uint64_t rn53(uint64_t hi, uint64_t lo, unsigned *p)
{
    const unsigned len = hi != 0 ? 64u + bitlen64(hi) : bitlen64(lo);
    uint64_t m;
    unsigned k;
    if (len <= 53) {
        *p = 0;
        return lo;
    }
    k = len - 53;   /* 1 .. 63 */
    m = (lo >> k) | (hi << (64 - k));
    if (((lo >> (k - 1)) & 1u) && ((k > 1 && (lo << (65 - k)) != 0) || (m & 1u))) {
        m++;
    }
    *p = k;
    return m;
}

/* RN53(hi:lo) in units of 2^sh of hi:lo's unit, sh <= the rounding position (exact) */
static uint64_t rn53_units(uint64_t hi, uint64_t lo, unsigned sh)
{
    unsigned p;
    const uint64_t m = rn53(hi, lo, &p);
    return m << (p - sh);
}

uint64_t tdoa_clock_ratio(uint32_t drx, uint32_t dtx)
{
    uint64_t n, q, r, half;
    if (dtx == 0 || 2u * (uint64_t)drx < dtx || drx >= 2u * (uint64_t)dtx) {
        return 0;
    }
    /* q = floor(drx 2^53 / dtx) in two long-division steps (q < 2^54), r the remainder */
    n = (uint64_t)drx << 21;
    q = n / dtx;
    r = n % dtx;
    n = r << 32;
    q = (q << 32) | (n / dtx);
    r = n % dtx;
    /* two more bits of the quotient (guard, sticky) decide the rounding: q >= 2^52, rounded at bit >= 2 */
    half = 2u * r >= dtx;
    return rn53_units(0, (q << 2) | (half << 1) | (uint64_t)(2u * r != (half ? (uint64_t)dtx : 0u)), 2);
}

int tdoa_clock_near(uint64_t cand, uint64_t cc)
{
    /* cand, cc in [0.5, 2] and this close: their double difference is exact (Sterbenz) */
    return (cand > cc ? cand - cc : cc - cand) < TDOA_CC_NOISE_FX;
}

uint64_t tdoa_clock_filter(uint64_t cc, uint64_t cand)
{
    /* 0.1 cc in [0.05, 0.2]: its double's ulp >= 2^-57; 0.9 cand in [0.45, 1.8]: ulp >= 2^-54. Both
     * exactly in units of 2^-57 (products in 2^-109 and 2^-106), their sum (< 2^59) too. */
    uint64_t hi, lo, a;
    mul64(MANT_0_1, cc, &hi, &lo);
    a = rn53_units(hi, lo, 52);
    mul64(MANT_0_9, cand, &hi, &lo);
    return rn53_units(0, a + rn53_units(hi, lo, 49), 4);   /* the sum in [0.5, 2]: ulp >= 2^-53 */
}

int64_t tdoa_clock_ticks(uint32_t drx, uint64_t delta, uint64_t cc)
{
    /* P = RN(delta cc) = m 2^p in units of 2^-53 (< 2^95, p <= 41); x = drx 2^53; d = |x - P| */
    uint64_t hi, lo, m, xh, xl, ph, pl;
    unsigned p;
    int neg;
    mul64(delta, cc, &hi, &lo);
    m = rn53(hi, lo, &p);
    ph = p != 0 ? m >> (64 - p) : 0;
    pl = m << p;
    xh = (uint64_t)drx >> 11;
    xl = (uint64_t)drx << 53;
    neg = xh < ph || (xh == ph && xl < pl);
    if (neg) {
        hi = ph - xh - (pl < xl);
        lo = pl - xl;
    } else {
        hi = xh - ph - (xl < pl);
        lo = xl - pl;
    }
    m = rn53(hi, lo, &p);   /* |RN(x - P)| = m 2^p, p <= 34: whole ticks by truncation */
    m >>= 53 - p;
    return neg ? -(int64_t)m : (int64_t)m;
}
