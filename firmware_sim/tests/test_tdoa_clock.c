/* The engine's integer clock arithmetic (tdoa_clock.h) against the host's IEEE double arithmetic, which
 * is what Bitcraze's tag code and the numpy twin compute: bit for bit on random and edge-case inputs. */
#include <math.h>
#include <stdint.h>

#include "tdoa_clock.h"
#include "tdoa_engine.h"
#include "time_ms.h"
#include "unit.h"

#define N_RANDOM 400000

static uint64_t rng = 0x9E3779B97F4A7C15ull;

static uint64_t next(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return rng;
}

/* uniform in [0, 1) */
static double unit(void)
{
    return (double)(next() >> 11) / 9007199254740992.0;
}

static uint64_t fx(double v)
{
    return (uint64_t)ldexp(v, 53);
}

/* A clock ratio as the engine holds it: a double in [0.5, 2], mostly within 30 ppm of 1. */
static double ratio(void)
{
    return (next() & 3u) == 0 ? 0.5 + 1.5 * unit() : 1.0 + 60e-6 * (unit() - 0.5);
}

static void test_ratio(void)
{
    static const uint32_t edge[][2] = {{1u, 1u}, {1u, 2u}, {2u, 1u}, {3u, 2u}, {0xFFFFFFFFu, 0xFFFFFFFFu},
                                       {0x7FFFFFFFu, 0xFFFFFFFFu}, {0x80000000u, 0xFFFFFFFFu}, {0u, 5u},
                                       {5u, 0u}, {0xFFFFFFFFu, 0x80000000u}, {0xFFFFFFFEu, 0x7FFFFFFFu}};
    unsigned i, bad = 0;
    for (i = 0; i < N_RANDOM + sizeof edge / sizeof edge[0]; i++) {
        uint32_t drx, dtx;
        double q;
        uint64_t want;
        if (i < sizeof edge / sizeof edge[0]) {
            drx = edge[i][0];
            dtx = edge[i][1];
        } else {
            dtx = (uint32_t)next() >> (next() % 24u);
            drx = (uint32_t)fmin(4294967295.0, floor((double)dtx * ((next() & 7u) == 0 ? 2.5 * unit() : ratio())));
        }
        q = dtx == 0 ? -1.0 : (double)drx / (double)dtx;
        want = q >= 0.5 && q < 2.0 ? fx(q) : 0u;
        bad += tdoa_clock_ratio(drx, dtx) != want;
    }
    CHECK(bad == 0);
}

static void test_near_and_bounds(void)
{
    unsigned i, bad = 0;
    for (i = 0; i < N_RANDOM; i++) {
        const double cc = (next() & 15u) == 0 ? 0.0 : ratio();
        const double cand = (next() & 1u) ? ratio() : (cc == 0.0 ? 1.0 : cc) + 8e-8 * (unit() - 0.5);
        const double dev = cand - cc;
        bad += tdoa_clock_near(fx(cand), fx(cc)) != (dev < TDOA_CC_ACCEPTED_NOISE && dev > -TDOA_CC_ACCEPTED_NOISE);
        bad += (fx(cand) > TDOA_CC_LOW_FX && fx(cand) < TDOA_CC_HIGH_FX) !=
               (cand > 1.0 - TDOA_CC_MAX_DEVIATION && cand < 1.0 + TDOA_CC_MAX_DEVIATION);
    }
    CHECK(bad == 0);
    CHECK(TDOA_CC_ONE == fx(1.0));
}

static void test_filter(void)
{
    unsigned i, bad = 0;
    for (i = 0; i < N_RANDOM; i++) {
        const double cc = ratio();
        const double cand = (next() & 1u) ? ratio() : fmin(2.0, fmax(0.5, cc + 3e-8 * (unit() - 0.5)));
        const double want = TDOA_CC_FILTER * cc + (1.0 - TDOA_CC_FILTER) * cand;
        bad += tdoa_clock_filter(fx(cc), fx(cand)) != fx(want);
    }
    CHECK(bad == 0);
    CHECK(tdoa_clock_filter(fx(2.0), fx(2.0)) == fx(2.0));
    CHECK(tdoa_clock_filter(fx(0.5), fx(0.5)) == fx(0.5));
}

static void test_ticks(void)
{
    unsigned i, bad = 0;
    for (i = 0; i < N_RANDOM; i++) {
        const double cc = ratio();
        const uint64_t delta = (next() >> (next() % 64u)) % ((1ull << 32) + 65535u);
        uint32_t drx;
        double want;
        if (next() & 1u) {   /* a real difference: a few metres around the interval, near whole ticks */
            const double d = floor((double)delta * cc) + (double)(int64_t)(next() % 4001u) - 2000.0;
            drx = (uint32_t)fmin(4294967295.0, fmax(0.0, d));
        } else {
            drx = (uint32_t)next();
        }
        want = (double)drx - (double)delta * cc;
        bad += tdoa_clock_ticks(drx, delta, fx(cc)) != (int64_t)want;
    }
    CHECK(bad == 0);
    CHECK(tdoa_clock_ticks(0u, 0u, fx(1.0)) == 0);
    CHECK(tdoa_clock_ticks(0xFFFFFFFFu, 0u, fx(2.0)) == 0xFFFFFFFFll);
    CHECK(tdoa_clock_ticks(0u, 0xFFFFFFFFull + 65535u, fx(2.0)) ==
          (int64_t)(0.0 - (double)(0xFFFFFFFFull + 65535u) * 2.0));
}

static void test_ms_of_us(void)
{
    static const uint64_t edge[] = {0u, 999u, 1000u, 0xFFFFFFFFull, 0x100000000ull, 4294967296000ull - 1u,
                                    4294967296000ull, 0xFFFFFFFFFFFFFFFFull};
    unsigned i, bad = 0;
    for (i = 0; i < sizeof edge / sizeof edge[0]; i++) {
        bad += uwb_ms_of_us(edge[i]) != (uint32_t)(edge[i] / 1000u);
    }
    for (i = 0; i < N_RANDOM; i++) {
        const uint64_t t = next() >> (next() % 64u);
        bad += uwb_ms_of_us(t) != (uint32_t)(t / 1000u);
    }
    CHECK(bad == 0);
}

int main(void)
{
    RUN(test_ms_of_us);
    RUN(test_ratio);
    RUN(test_near_and_bounds);
    RUN(test_filter);
    RUN(test_ticks);
    return UNIT_DONE();
}
