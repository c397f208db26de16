/* Finding 0x00 bytes a 32-bit word at a time (the COBS encoder and the frame receiver): plain integer
 * instructions, also under an emulator (newlib's memchr uses uadd8/sel, a helper call each in QEMU). */
#ifndef UWB_ZERO_BYTES_H
#define UWB_ZERO_BYTES_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__ && defined(__GNUC__)
#define UWB_ZERO_BYTES_LE 1
#else
#define UWB_ZERO_BYTES_LE 0
#endif

/* The zero-byte test of 4 bytes (little-endian word w): bit 7 of every byte that is 0x00 set, and of no byte
 * below the first zero; a byte above a zero may be flagged falsely (a borrow), so those need a check. The same
 * test is core/id_table.h's (proto/ and core/ may not include each other: docs/ARCHITECTURE.md). */
static inline uint32_t zero_flags(uint32_t w)
{
    return (w - 0x01010101u) & ~w & 0x80808080u;
}

/* The byte index (0..3) of the lowest flag of zero_flags() != 0: with little-endian loads the first 0x00. */
static inline size_t lowest_flag_byte(uint32_t z)
{
#if UWB_ZERO_BYTES_LE
    return (size_t)__builtin_ctz(z) >> 3; /* rbit + clz on the Cortex-M4 */
#else
    size_t k = 0;
    while ((z & 0x80u) == 0u) {
        z >>= 8;
        k++;
    }
    return k;
#endif
}

/* The first 0x00 in [p, end), or NULL: as memchr(p, 0, end - p). */
static inline const uint8_t *find_zero(const uint8_t *p, const uint8_t *end)
{
#if UWB_ZERO_BYTES_LE
    while (end - p >= 4) {
        uint32_t w;
        uint32_t z;
        memcpy(&w, p, sizeof w);
        z = zero_flags(w);
        if (z != 0u) {
            return p + lowest_flag_byte(z);
        }
        p += 4;
    }
#endif
    for (; p != end; p++) {
        if (*p == 0) {
            return p;
        }
    }
    return NULL;
}

#endif
