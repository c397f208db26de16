/* Shared by the libFuzzer targets: a deterministic cost clock and a checker of device output. */
#ifndef UWB_FUZZ_COMMON_H
#define UWB_FUZZ_COMMON_H

#include <stddef.h>
#include <stdint.h>

#include "frame_rx.h"

void fuzz_clock_reset(void);

/* Abort (a finding for libFuzzer) with a message; used for violated invariants. */
void fuzz_fail(const char *what);

/* Checks device -> host output: every byte belongs to a valid frame of a to-host type with a
 * correct CRC, finite RESULT fields, and nothing but whole frames. */
typedef struct {
    frame_rx_t rx;
    size_t frames;
    size_t results, errors, stats, hello_replies;
} out_checker_t;

void out_checker_init(out_checker_t *oc);
void out_checker_feed(out_checker_t *oc, const uint8_t *data, size_t n);

#endif
