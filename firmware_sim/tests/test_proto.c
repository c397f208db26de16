/* Wire protocol: golden vectors decode and re-encode byte-identically; COBS, CRC, frame receiver. */
#include <stdlib.h>
#include <string.h>

#include "cobs.h"
#include "frame_rx.h"
#include "unit.h"
#include "uwb_msgs.h"
#include "uwb_msgs_format.h"

#ifndef UWB_REPO_ROOT
#define UWB_REPO_ROOT ".."
#endif

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static size_t from_hex(const char *hex, uint8_t *out, size_t cap)
{
    size_t n = 0;
    while (hex[0] && hex[1] && n < cap) {
        out[n++] = (uint8_t)(hexval(hex[0]) * 16 + hexval(hex[1]));
        hex += 2;
    }
    return n;
}

static void test_crc32c_check_value(void)
{
    CHECK(uwb_crc32c((const uint8_t *)"123456789", 9) == 0xE3069283u);
    CHECK(uwb_crc32c(NULL, 0) == 0u);
}

static void test_cobs_roundtrip(void)
{
    uint8_t src[300], enc[310], dec[300];
    size_t n, i;
    unsigned seed = 12345;
    for (n = 0; n < 300; n++) {
        size_t m;
        long d;
        for (i = 0; i < n; i++) {
            seed = seed * 1103515245u + 12345u;
            src[i] = (uint8_t)((n % 3 == 0) ? 0 : (seed >> 16));
        }
        m = cobs_encode(src, n, enc);
        CHECK(m >= n + 1 && m <= n + 1 + n / 254);
        CHECK(memchr(enc, 0, m) == NULL);
        d = cobs_decode(enc, m, dec, sizeof dec);
        CHECK(d == (long)n);
        CHECK(memcmp(src, dec, n) == 0);
    }
}

/* In place, one pass (what the firmware sends with): the same bytes as cobs_encode for every length it
 * allows (0..253) and zero densities from none to all. */
static void test_cobs_encode_inplace_matches(void)
{
    uint8_t src[253], enc[260], buf[260];
    size_t n, i;
    unsigned seed = 777, density;
    for (density = 0; density <= 8; density += 2) {
        for (n = 0; n <= sizeof src; n++) {
            for (i = 0; i < n; i++) {
                seed = seed * 1103515245u + 12345u;
                src[i] = (uint8_t)(((seed >> 13) % 8u) < density ? 0u : 1u + (seed >> 16) % 255u);
            }
            memcpy(buf + 1, src, n);
            CHECK(cobs_encode_inplace(buf, n) == cobs_encode(src, n, enc));
            CHECK(memcmp(buf, enc, n + 1) == 0);
        }
    }
}

static void test_cobs_rejects_garbage(void)
{
    const uint8_t zero_inside[] = {0x03, 0x11, 0x00};
    const uint8_t runs_past[] = {0x05, 0x11, 0x22};
    uint8_t dst[8];
    CHECK(cobs_decode(zero_inside, sizeof zero_inside, dst, sizeof dst) < 0);
    CHECK(cobs_decode(runs_past, sizeof runs_past, dst, sizeof dst) < 0);
    CHECK(cobs_decode((const uint8_t *)"\x09\x01\x02\x03\x04\x05\x06\x07\x08", 9, dst, 4) < 0); /* too big */
}

static void test_frame_rx_resync_and_oversize(void)
{
    frame_rx_t rx;
    const uint8_t *f = NULL;
    size_t len = 0, i;
    int frames = 0, oversize = 0;
    frame_rx_init(&rx);
    /* garbage longer than any frame, then a delimiter, then a 3-byte frame */
    for (i = 0; i < 600; i++) {
        frame_rx_event_t ev = frame_rx_push(&rx, (uint8_t)(1 + i % 200), &f, &len);
        CHECK(ev == FRAME_RX_NONE);
    }
    oversize += frame_rx_push(&rx, 0, &f, &len) == FRAME_RX_OVERSIZE;
    frame_rx_push(&rx, 0x11, &f, &len);
    frame_rx_push(&rx, 0x22, &f, &len);
    frame_rx_push(&rx, 0x33, &f, &len);
    frames += frame_rx_push(&rx, 0, &f, &len) == FRAME_RX_FRAME;
    CHECK(oversize == 1);
    CHECK(frames == 1);
    CHECK(len == 3 && f[0] == 0x11 && f[2] == 0x33);
    /* empty frames (double delimiters) produce nothing */
    CHECK(frame_rx_push(&rx, 0, &f, &len) == FRAME_RX_NONE);
}

/* Any single flipped bit of a body must be caught by the CRC or the framing (every 7th bit). */
static void check_bit_flips(uint8_t *body, size_t blen)
{
    size_t bit;
    for (bit = 0; bit < blen * 8; bit += 7) {
        uwb_msg_t junk;
        body[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        CHECK(uwb_body_decode(body, blen, &junk) != UWB_DECODE_OK);
        body[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
}

/* One line of vectors.txt ("name seq frame-hex MsgName field=value ..."): the frame decodes to those fields
 * and re-encodes to the same bytes. 1 when the line was a vector that decoded, else 0. */
static int check_golden_vector(char *line)
{
    char name[64], hex[1024], msgname[32];
    unsigned seq;
    int consumed = 0;
    uint8_t frame[512], body[UWB_MAX_BODY], reenc_body[UWB_MAX_BODY], reenc[UWB_MAX_ENCODED + 1];
    size_t flen, blen_re, elen;
    long blen;
    uwb_msg_t msg;
    char fields[2048];
    const char *expect_fields;
    if (line[0] == '#' || line[0] == '\n') {
        return 0;
    }
    line[strcspn(line, "\n")] = 0;
    if (sscanf(line, "%63s %u %1023s %31s%n", name, &seq, hex, msgname, &consumed) != 4) {
        CHECK(0);
        return 0;
    }
    expect_fields = line + consumed; /* " field=value ..." or "" */
    flen = from_hex(hex, frame, sizeof frame);
    CHECK(flen >= 2 && frame[flen - 1] == 0);
    blen = cobs_decode(frame, flen - 1, body, sizeof body);
    CHECK(blen > 0);
    if (blen <= 0) return 0;
    CHECK(uwb_body_decode(body, (size_t)blen, &msg) == UWB_DECODE_OK);
    CHECK(msg.seq == seq);
    CHECK(uwb_msg_format(&msg, fields, sizeof fields) == 1);
    if (strcmp(fields, expect_fields) != 0) {
        fprintf(stderr, "vector %s: fields differ\n  C:      %s\n  golden: %s\n", name, fields, expect_fields);
        CHECK(0);
    }
    blen_re = uwb_body_encode(&msg, reenc_body);
    elen = cobs_encode(reenc_body, blen_re, reenc);
    reenc[elen++] = 0;
    CHECK(elen == flen && memcmp(reenc, frame, flen) == 0);
    check_bit_flips(body, (size_t)blen);
    return 1;
}

static void test_golden_vectors(void)
{
    char path[512];
    char line[4096];
    FILE *fh;
    int vectors = 0;
    snprintf(path, sizeof path, "%s/protocol/golden/vectors.txt", UWB_REPO_ROOT);
    fh = fopen(path, "r");
    CHECK(fh != NULL);
    if (fh == NULL) {
        fprintf(stderr, "cannot open %s\n", path);
        return;
    }
    while (fgets(line, sizeof line, fh)) {
        vectors += check_golden_vector(line);
    }
    fclose(fh);
    CHECK(vectors >= 15);
    printf("  (%d golden vectors)\n", vectors);
}

static void test_body_decode_errors(void)
{
    uint8_t body[UWB_MAX_BODY];
    uwb_msg_t msg;
    size_t n;
    uint32_t crc;
    memset(&msg, 0, sizeof msg);
    msg.type = UWB_MSG_TWR;
    msg.seq = 42;
    msg.u.twr.t_us = 1;
    msg.u.twr.anchor_id = 2;
    msg.u.twr.range = 3.0f;
    n = uwb_body_encode(&msg, body);
    CHECK(n == UWB_HEADER_SIZE + UWB_MSG_TWR_LEN + UWB_CRC_SIZE);
    CHECK(uwb_body_decode(body, 5, &msg) == UWB_DECODE_SHORT);
    /* unknown type with a valid crc */
    body[0] = 0x7E;
    crc = uwb_crc32c(body, n - 4);
    body[n - 4] = (uint8_t)crc; body[n - 3] = (uint8_t)(crc >> 8);
    body[n - 2] = (uint8_t)(crc >> 16); body[n - 1] = (uint8_t)(crc >> 24);
    CHECK(uwb_body_decode(body, n, &msg) == UWB_DECODE_UNKNOWN_TYPE);
    /* TWR header with one payload byte too few and a valid crc */
    body[0] = UWB_MSG_TWR;
    crc = uwb_crc32c(body, n - 5);
    body[n - 5] = (uint8_t)crc; body[n - 4] = (uint8_t)(crc >> 8);
    body[n - 3] = (uint8_t)(crc >> 16); body[n - 2] = (uint8_t)(crc >> 24);
    CHECK(uwb_body_decode(body, n - 1, &msg) == UWB_DECODE_BAD_LENGTH);
}

int main(void)
{
    RUN(test_crc32c_check_value);
    RUN(test_cobs_roundtrip);
    RUN(test_cobs_encode_inplace_matches);
    RUN(test_cobs_rejects_garbage);
    RUN(test_frame_rx_resync_and_oversize);
    RUN(test_golden_vectors);
    RUN(test_body_decode_errors);
    return UNIT_DONE();
}
