/* Consistent Overhead Byte Stuffing: an encoded frame holds no 0x00, so 0x00 delimits frames and
 * a receiver resynchronises on the next delimiter after any garbage. */
#ifndef UWB_COBS_H
#define UWB_COBS_H

#include <stddef.h>
#include <stdint.h>

/* Encode n bytes into dst (room for n + n/254 + 1 bytes); returns the encoded length (no delimiter). */
size_t cobs_encode(const uint8_t *src, size_t n, uint8_t *dst);

/* The same bytes as cobs_encode, in place and in one pass: the n data bytes are at buf[1..n], n <= 253
 * (one code byte in front, no 0xFF code: every frame of this protocol); each 0x00 becomes the distance
 * to the next one and buf[0] the distance to the first. Returns n + 1. */
size_t cobs_encode_inplace(uint8_t *buf, size_t n);

/* Decode n bytes (no delimiter) into dst of capacity cap; returns the decoded length or -1 if the
 * input is not valid COBS or does not fit. */
long cobs_decode(const uint8_t *src, size_t n, uint8_t *dst, size_t cap);

#endif
