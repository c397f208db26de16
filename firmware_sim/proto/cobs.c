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

size_t cobs_encode_inplace(uint8_t *buf, size_t n)
{
    size_t code_pos = 0;
    size_t i = 1;
    while (i <= n) {
        uint32_t w;
        if (n - i >= 4u) {
            memcpy(&w, buf + i, sizeof w);
            if (((w - 0x01010101u) & ~w & 0x80808080u) == 0u) { /* no 0x00 among these 4 bytes */
                i += 4u;
                continue;
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
