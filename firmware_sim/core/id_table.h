/* The first of 16 slots holding an 8-bit id, four ids compared per step: in each word of four ids,
 * id ^ word has a zero byte where they are equal, and (x - 0x01..) & ~x & 0x80.. marks the lowest zero
 * byte exactly. Used by the TDoA engine's remote/ToF tables and the estimator's anchor table. The same
 * zero-byte test as proto/zero_bytes.h's zero_flags(): core/ and proto/ may not include each other
 * (docs/ARCHITECTURE.md), so each keeps its one line. */
#ifndef UWB_ID_TABLE_H
#define UWB_ID_TABLE_H

#include <stdint.h>
#include <string.h>

static inline unsigned id_table_ctz(uint32_t v)
{
#if defined(__GNUC__)
    return (unsigned)__builtin_ctz(v);
#else
    unsigned n = 0;
    while (!(v & 1u)) {
        v >>= 1;
        n++;
    }
    return n;
#endif
}

/* ids[w .. w+3] as a little-endian word (one load on little-endian targets) */
static inline uint32_t id_table_word(const uint8_t *ids)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    uint32_t x;
    memcpy(&x, ids, sizeof x);
    return x;
#else
    return (uint32_t)ids[0] | ((uint32_t)ids[1] << 8) | ((uint32_t)ids[2] << 16) | ((uint32_t)ids[3] << 24);
#endif
}

/* The first k < 16 with ids[k] == id, or -1. */
static inline int id_table_first(const uint8_t *ids, uint8_t id)
{
    const uint32_t pat = 0x01010101u * id;
    unsigned w;
    for (w = 0; w < 16u; w += 4u) {
        const uint32_t x = id_table_word(ids + w) ^ pat;
        const uint32_t z = (x - 0x01010101u) & ~x & 0x80808080u;
        if (z != 0) {
            return (int)(w + id_table_ctz(z) / 8u);
        }
    }
    return -1;
}

#endif
