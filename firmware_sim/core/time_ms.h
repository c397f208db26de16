/* Whole milliseconds of a microsecond time, mod 2^32: (uint32_t)(t_us / 1000) exactly, by long division
 * in 16-bit digits (three 32-bit divisions: the M4 has no 64-bit divide, and libgcc's takes ~100
 * instructions). The clock of every expiry (TDoA engine, radio anchor positions). */
#ifndef UWB_TIME_MS_H
#define UWB_TIME_MS_H

#include <stdint.h>

uint32_t uwb_ms_of_us(uint64_t t_us);

/* (float)d for a 64-bit time difference: one 32-bit VCVT when d fits 32 bits (libgcc's 64-bit conversion
 * takes ~95 instructions on the M4). Both conversions round the same integer to nearest: the same float. */
static inline float uwb_u64_to_float(uint64_t d)
{
    return d <= UINT32_MAX ? (float)(uint32_t)d : (float)d;
}

static inline float uwb_i64_to_float(int64_t d)
{
    return d >= INT32_MIN && d <= INT32_MAX ? (float)(int32_t)d : (float)d;
}

#endif
