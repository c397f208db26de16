/* libFuzzer target 2: the whole firmware input path. Arbitrary bytes -> firmware_feed (parser ->
 * dispatch -> estimator -> reply frames). The first input byte chooses how the rest is cut into
 * chunks (the device must not care how bytes arrive). Invariants:
 *   - no crash, leak or undefined behaviour (ASan + UBSan);
 *   - every output byte belongs to a valid to-host frame; RESULT fields are finite;
 *   - the estimator state stays finite; the full covariance exactly symmetric and within its bounds;
 *   - the output does not depend on the chunking (feeding the same bytes in one call gives the
 *     same output, with the deterministic cost clock);
 *   - STATS accounting: each measurement frame either got a RESULT or was counted as dropped. */
#include <math.h>
#include <string.h>

#include "firmware.h"
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define OUT_CAP (1u << 20)

typedef struct {
    uint8_t buf[OUT_CAP];
    size_t len;
    size_t total;
    out_checker_t check;
} sink_t;

static sink_t sink_a, sink_b;  /* static: 1 MiB each is too much for the stack */
static firmware_t fw_a, fw_b;

static void sink_write(void *ctx, const uint8_t *data, size_t n)
{
    sink_t *s = (sink_t *)ctx;
    out_checker_feed(&s->check, data, n);
    if (s->len + n <= sizeof s->buf) {
        memcpy(s->buf + s->len, data, n);
        s->len += n;
    }
    s->total += n;
}

static void sink_init(sink_t *s)
{
    s->len = 0;
    s->total = 0;
    out_checker_init(&s->check);
}

static void check_state(const firmware_t *fw)
{
    float pos[3], vel[3], quat[4], var[9];
    int i;
    estimator_state(&fw->est, pos, vel, quat, var);
    for (i = 0; i < 3; i++) {
        if (!isfinite(pos[i]) || !isfinite(vel[i])) {
            fuzz_fail("estimator state not finite");
        }
    }
    for (i = 0; i < 9; i++) {
        if (!isfinite(var[i]) || var[i] < 0.0f) {
            fuzz_fail("covariance diagonal not finite or negative");
        }
    }
    /* The clamp runs after every covariance operation: P is exactly symmetric and bounded. */
    for (i = 0; i < EKF_N; i++) {
        int j;
        for (j = 0; j < EKF_N; j++) {
            const float a = fw->est.ekf.P[i][j];
            if (!(fabsf(a) <= EKF_P_MAX) || a != fw->est.ekf.P[j][i] || (i == j && !(a >= EKF_P_MIN))) {
                fuzz_fail("covariance not symmetric or outside its bounds");
            }
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t i, chunk;
    const fw_stats_t *s;
    size_t counted, k;
    if (size == 0) {
        return 0;
    }
    chunk = (size_t)data[0] % 17u + 1u;
    data++;
    size--;

    fuzz_clock_reset();
    sink_init(&sink_a);
    firmware_init(&fw_a, sink_write, &sink_a, "fuzz");
    for (i = 0; i < size; i += chunk) {
        size_t n = size - i < chunk ? size - i : chunk;
        firmware_feed(&fw_a, data + i, n);
        check_state(&fw_a);
    }

    fuzz_clock_reset();
    sink_init(&sink_b);
    firmware_init(&fw_b, sink_write, &sink_b, "fuzz");
    firmware_feed(&fw_b, data, size);

    if (sink_a.total != sink_b.total || sink_a.len != sink_b.len ||
        memcmp(sink_a.buf, sink_b.buf, sink_a.len) != 0) {
        fuzz_fail("output depends on how the input was chunked");
    }
    if (memcmp(&fw_a.stats, &fw_b.stats, sizeof fw_a.stats) != 0) {
        fuzz_fail("counters depend on how the input was chunked");
    }
    s = &fw_a.stats;
    if (s->results != sink_a.check.results) {
        fuzz_fail("stats.results differs from the RESULT frames sent");
    }
    /* Finite measurements are counted by kind in meas (or radio_meas: formed by the TDoA engine) and
     * end in a RESULT or a drop; non-finite ones are dropped before being counted (and also counted in
     * non_finite). */
    counted = s->radio_meas;
    for (k = 0; k < MM_KIND_END; k++) {
        counted += s->meas[k];
    }
    if ((size_t)s->results + s->dropped_meas < counted ||
        (size_t)s->results + s->dropped_meas - counted > s->non_finite) {
        fuzz_fail("measurement accounting");
    }
    /* Every radio packet formed a measurement or was dropped for one counted reason. */
    if (s->radio_packets != s->radio_meas + s->radio_no_reference + s->radio_clock + s->radio_expired +
                                s->radio_malformed + s->radio_unknown_type + s->radio_no_position) {
        fuzz_fail("radio packet accounting");
    }
    return 0;
}
