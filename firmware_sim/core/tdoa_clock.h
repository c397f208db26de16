/* The TDoA engine's clock-correction arithmetic in integers, giving exactly what IEEE double arithmetic
 * (Bitcraze's clockCorrectionEngine / calcTDoA, and the numpy twin) gives, without soft-float double.
 *
 * A clock ratio cc is kept in units of 2^-53 (uint64): every double in [0.5, 2] is exactly such a value
 * (its ulp is 2^-53 or 2^-52 there). The double operations of the engine are reproduced one by one with
 * their round-to-nearest-even to 53 significant bits, computed on exact 128-bit integer products:
 *   candidate = drx / dtx,   filtered cc = 0.1 cc + 0.9 candidate,   ticks = (int64)(drx - delta cc).
 * A ratio outside [0.5, 2) is not a clock ratio: it is never stored (docs/radio.md; the double engine
 * would only differ for a ratio below 3e-8 met while the anchor has no estimate yet).
 * tests/test_tdoa_clock.c checks every function against the host's double arithmetic, bit for bit. */
#ifndef UWB_TDOA_CLOCK_H
#define UWB_TDOA_CLOCK_H

#include <stdint.h>

#define TDOA_CC_ONE 0x20000000000000ull          /* 1.0 in units of 2^-53 */
#define TDOA_CC_NOISE_FX 270215978ull           /* |cand - cc| < 0.03e-6 (double) <=> |diff| < this */
#define TDOA_CC_LOW_FX 9007019110755897ull      /* double(1 - 20e-6) in units of 2^-53 */
#define TDOA_CC_HIGH_FX 9007379398726086ull     /* double(1 + 20e-6) */

/* RN(drx / dtx) in units of 2^-53 when 0.5 <= drx / dtx < 2, else 0 (no clock ratio; dtx 0 too). */
uint64_t tdoa_clock_ratio(uint32_t drx, uint32_t dtx);

/* 1 if |cand - cc| < 0.03e-6 as the double comparison decides it (cc 0 = unknown: never). */
int tdoa_clock_near(uint64_t cand, uint64_t cc);

/* RN(RN(0.1 cc) + RN(0.9 cand)) with the doubles 0.1 and 0.9 (= 1.0 - 0.1); cc, cand in [0.5, 2]. */
uint64_t tdoa_clock_filter(uint64_t cc, uint64_t cand);

/* (int64)RN(drx - RN(delta cc)): the difference in whole ticks, truncated toward zero; delta < 2^40. */
int64_t tdoa_clock_ticks(uint32_t drx, uint64_t delta, uint64_t cc);

#endif
