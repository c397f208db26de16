/* Whole milliseconds of a microsecond time, mod 2^32: (uint32_t)(t_us / 1000) exactly, by long division
 * in 16-bit digits (three 32-bit divisions: the M4 has no 64-bit divide, and libgcc's takes ~100
 * instructions). The clock of every expiry (TDoA engine, radio anchor positions). */
#ifndef UWB_TIME_MS_H
#define UWB_TIME_MS_H

#include <stdint.h>

static inline uint32_t uwb_ms_of_us(uint64_t t_us)
{
    const uint32_t hi = (uint32_t)(t_us >> 32), lo = (uint32_t)t_us;
    uint32_t r = hi % 1000u, n, q1;
    n = (r << 16) | (lo >> 16);   /* r < 1000: n < 2^26 */
    q1 = n / 1000u;
    r = n % 1000u;
    n = (r << 16) | (lo & 0xFFFFu);
    return (q1 << 16) + n / 1000u;   /* the quotient's low 32 bits: q1, n / 1000 < 2^16 */
}

#endif
