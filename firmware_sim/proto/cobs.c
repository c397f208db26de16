#include "cobs.h"

#include <string.h>

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

/* The first 0x00 among the 4 bytes at p (little-endian word w), 4 if none: the lowest flag of the zero-byte
 * test is always a zero byte (borrows only flag bytes above one), so its position is exact. */
static size_t first_zero(uint32_t w, const uint8_t *p)
{
    const uint32_t z = (w - 0x01010101u) & ~w & 0x80808080u;
    if (z == 0u) {
        return 4u;
    }
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__ && defined(__GNUC__)
    (void)p;
    return (size_t)__builtin_ctz(z) >> 3; /* rbit + clz on the Cortex-M4 */
#else
    {
        size_t k = 0;
        while (p[k] != 0) {
            k++;
        }
        return k;
    }
#endif
}

size_t cobs_encode_inplace(uint8_t *buf, size_t n)
{
    size_t code_pos = 0;
    size_t i = 1;
    while (i <= n) {
        if (n - i >= 4u) {
            uint32_t w;
            size_t k;
            memcpy(&w, buf + i, sizeof w);
            k = first_zero(w, buf + i);
            i += k;
            if (k == 4u) {
                continue; /* no 0x00 among these 4 bytes */
            }
        }
        if (buf[i] == 0) {
            buf[code_pos] = (uint8_t)(i - code_pos);
            code_pos = i;
        }
        i++;
    }
    buf[code_pos] = (uint8_t)(n + 1u - code_pos);
    return n + 1u;
}
