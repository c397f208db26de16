/* Whole milliseconds of a microsecond time, mod 2^32: (uint32_t)(t_us / 1000) exactly, by long division
 * in 16-bit digits (three 32-bit divisions: the M4 has no 64-bit divide, and libgcc's takes ~100
 * instructions). The clock of every expiry (TDoA engine, radio anchor positions). */
#ifndef UWB_TIME_MS_H
#define UWB_TIME_MS_H

#include <stdint.h>

uint32_t uwb_ms_of_us(uint64_t t_us);

#endif
