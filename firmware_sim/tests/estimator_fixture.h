/* Shared by the estimator tests (test_estimator*.c): one estimator in a box of 8 anchors, the exact
 * range to an anchor, and a stationary tag's measurement stream. Header-only (static inline): each test
 * program is one translation unit with its own unit.h counters. */
#ifndef UWB_ESTIMATOR_FIXTURE_H
#define UWB_ESTIMATOR_FIXTURE_H

#include <stddef.h>
#include <string.h>

#include "estimator.h"
#include "unit.h"

static const bias_model_t no_model = {NULL, NULL, 0};
static estimator_t est; /* large: keep off the stack */

/* 8 anchors at the corners of a 7 x 8 x 3 m box centred at the origin, z from 0 to 3. */
static inline void set_box_anchors(estimator_t *e)
{
    int i;
    for (i = 0; i < 8; i++) {
        const float p[3] = {(i & 1) ? 3.5f : -3.5f, (i & 2) ? 4.0f : -4.0f, (i & 4) ? 3.0f : 0.0f};
        CHECK(estimator_set_anchor(e, (uint8_t)i, p) == EST_OK);
    }
}

static inline float range_to(const estimator_t *e, uint8_t id, const float p[3])
{
    const float *a = e->anchors[id];
    return sqrtf((p[0] - a[0]) * (p[0] - a[0]) + (p[1] - a[1]) * (p[1] - a[1]) + (p[2] - a[2]) * (p[2] - a[2]));
}

static inline void setup(uint8_t mode, uint8_t stages, float x, float y, float z)
{
    estimator_config_t cfg;
    estimator_init(&est, &no_model);
    estimator_default_config(&cfg);
    cfg.mode = mode;
    cfg.stages = stages;
    cfg.init_x = x;
    cfg.init_y = y;
    cfg.init_z = z;
    estimator_configure(&est, &cfg, 1);
    set_box_anchors(&est);
}

static const float still_acc[3] = {0.0f, 0.0f, EKF_GRAVITY};
static const float no_gyro[3] = {0.0f, 0.0f, 0.0f};

/* Stationary tag, IMU at 1 kHz, TWR round robin at 100 Hz, noiseless. */
static inline void run_static(const float truth[3], int seconds)
{
    estimator_result_t r;
    uint64_t t;
    uint8_t k = 0;
    for (t = 0; t <= (uint64_t)seconds * 1000000u; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
        if (t % 10000 == 5000) {
            CHECK(estimator_on_twr(&est, t, k, range_to(&est, k, truth), &r) == EST_OK);
            k = (uint8_t)((k + 1) % 8);
        }
    }
}

#endif
