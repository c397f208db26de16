#include "cobs.h"

#include <string.h>

#include "zero_bytes.h"

size_t cobs_encode(const uint8_t *src, size_t n, uint8_t *dst)
{
    size_t code_pos = 0;
    size_t out = 1;
    uint8_t code = 1;
    size_t i;
    for (i = 0; i < n; i++) {
        if (src[i] == 0) {
            dst[code_pos] = code;
            code_pos = out++;
            code = 1;
        } else {
            dst[out++] = src[i];
            code++;
            if (code == 0xFF) {
                dst[code_pos] = code;
                code_pos = out++;
                code = 1;
            }
        }
    }
    dst[code_pos] = code;
    return out;
}

long cobs_decode(const uint8_t *src, size_t n, uint8_t *dst, size_t cap)
{
    size_t i = 0;
    size_t out = 0;
    while (i < n) {
        uint8_t code = src[i];
        size_t k;
        if (code == 0 || i + code > n) {
            return -1;
        }
        for (k = 1; k < code; k++) {
            if (src[i + k] == 0 || out >= cap) {
                return -1;
            }
            dst[out++] = src[i + k];
        }
        i += code;
        if (code != 0xFF && i < n) {
            if (out >= cap) {
                return -1;
            }
            dst[out++] = 0;
        }
    }
    return (long)out;
}

#if UWB_ZERO_BYTES_LE
/* Every 0x00 of the 4 bytes at buf[i..i+3] (flags z != 0) in turn, straight from the flags: the index of the
 * last one (the next code byte's position). */
static size_t code_zeros(uint8_t *buf, size_t i, uint32_t z, size_t code_pos)
{
    do {
        const size_t at = i + lowest_flag_byte(z);
        if (buf[at] == 0) {
            buf[code_pos] = (uint8_t)(at - code_pos);
            code_pos = at;
        }
        z &= z - 1u;
    } while (z != 0u);
    return code_pos;
}
#else
static size_t code_zeros(uint8_t *buf, size_t i, uint32_t z, size_t code_pos)
{
    size_t k;
    (void)z;
    for (k = i; k < i + 4u; k++) {
        if (buf[k] == 0) {
            buf[code_pos] = (uint8_t)(k - code_pos);
            code_pos = k;
        }
    }
    return code_pos;
}
#endif

size_t cobs_encode_inplace(uint8_t *buf, size_t n)
{
    size_t code_pos = 0;
    size_t i = 1;
    for (; i + 3u <= n; i += 4u) { /* whole words: buf[i..i+3] */
        uint32_t w;
        uint32_t z;
        memcpy(&w, buf + i, sizeof w);
        z = zero_flags(w); /* exact for "no zero": any flag then means some 0x00 */
        if (z != 0u) {
            code_pos = code_zeros(buf, i, z, code_pos);
        }
    }
    for (; i <= n; i++) {
        if (buf[i] == 0) {
            buf[code_pos] = (uint8_t)(i - code_pos);
            code_pos = i;
        }
    }
    buf[code_pos] = (uint8_t)(n + 1u - code_pos);
    return n + 1u;
}
