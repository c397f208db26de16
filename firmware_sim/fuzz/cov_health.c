/* cov_health: feed a wire byte stream (stdin) to the firmware in-process and check the FULL covariance
 * after every RESULT, which the wire only shows as a diagonal: finite, exactly symmetric, bounded
 * (|P_ij| <= EKF_P_MAX, P_ii >= EKF_P_MIN) and positive definite (Cholesky in double).
 * Used by tests/device/test_long_flight.py. Output (stdout), one line:
 *   results N checks N asym_max X max_abs X min_pivot X not_pd N non_finite N out_of_bounds N
 *   diverged_errors N */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cobs.h"
#include "cov_check.h"
#include "ekf_core.h"
#include "firmware.h"

typedef struct {
    const firmware_t *fw;
    frame_rx_t rx;
    unsigned long results, checks, not_pd, non_finite, out_of_bounds, diverged;
    double asym_max, max_abs, min_pivot;
} health_t;

static void check_p(health_t *h)
{
    const float(*P)[EKF_N] = (const float(*)[EKF_N])h->fw->est.ekf.P;
    double pivot;
    int i, j, bad = 0;
    h->checks++;
    for (i = 0; i < EKF_N; i++) {
        for (j = 0; j < EKF_N; j++) {
            double a = P[i][j], d = fabs((double)P[i][j] - (double)P[j][i]);
            if (!isfinite(a)) {
                h->non_finite++;
                return;
            }
            if (d > h->asym_max) {
                h->asym_max = d;
            }
            if (fabs(a) > h->max_abs) {
                h->max_abs = fabs(a);
            }
            if (fabs(a) > EKF_P_MAX || (i == j && a < EKF_P_MIN)) {
                bad = 1;
            }
        }
    }
    h->out_of_bounds += (unsigned long)bad;
    pivot = cov_min_pivot(&P[0][0]);
    if (pivot < h->min_pivot) {
        h->min_pivot = pivot;
    }
    h->not_pd += (unsigned long)!(pivot > 0.0);
}

static void on_output(void *ctx, const uint8_t *data, size_t n)
{
    health_t *h = (health_t *)ctx;
    size_t i;
    for (i = 0; i < n; i++) {
        const uint8_t *frame = NULL;
        size_t len = 0;
        if (frame_rx_push(&h->rx, data[i], &frame, &len) == FRAME_RX_FRAME) {
            uint8_t body[UWB_MAX_BODY];
            uwb_msg_t msg;
            long m = cobs_decode(frame, len, body, sizeof body);
            if (m >= 0 && uwb_body_decode(body, (size_t)m, &msg) == UWB_DECODE_OK) {
                if (msg.type == UWB_MSG_RESULT) {
                    h->results++;
                    check_p(h);
                } else if (msg.type == UWB_MSG_ERROR && msg.u.error.code == UWB_ERROR_CODE_DIVERGED) {
                    h->diverged++;
                }
            }
        }
    }
}

static firmware_t fw;  /* static: the firmware state is a few KiB */

int main(void)
{
    static uint8_t buf[1 << 16];
    health_t h;
    size_t n;
    memset(&h, 0, sizeof h);
    h.fw = &fw;
    h.min_pivot = INFINITY;
    frame_rx_init(&h.rx);
    firmware_init(&fw, on_output, &h, "health");
    while ((n = fread(buf, 1, sizeof buf, stdin)) > 0) {
        firmware_feed(&fw, buf, n);
    }
    printf("results %lu checks %lu asym_max %.9g max_abs %.9g min_pivot %.9g not_pd %lu non_finite %lu "
           "out_of_bounds %lu diverged_errors %lu\n", h.results, h.checks, h.asym_max, h.max_abs, h.min_pivot,
           h.not_pd, h.non_finite, h.out_of_bounds, h.diverged);
    return 0;
}
