/* Per anchor pair monitor of the bias network's corrections: a pair on which the correction makes the
 * innovations worse than no correction would is switched off (for the rest of the flight) and counted.
 * The network is trained on some places and constellations; this is what protects the rest. */
#ifndef UWB_NN_MONITOR_H
#define UWB_NN_MONITOR_H

#include <stdint.h>

#define NN_MON_ANCHORS 16          /* = ESTIMATOR_MAX_ANCHORS */
#define NN_MON_ALPHA (1.0f / 64.0f) /* exponential averages over ~64 measurements of the pair */
#define NN_MON_MIN_SAMPLES 64u     /* no verdict before */
#define NN_MON_WORSE 1.25f         /* corrected mean square above 1.25 x the uncorrected: off */
#define NN_MON_CLIP 9.0f           /* y^2 clipped at 9 S: a few gross outliers do not decide */

typedef struct {
    float ms_corr; /* average of min(y^2, 9 S), y = z - bias - h (what the filter sees) */
    float ms_raw;  /* the same without the correction, y + bias */
    uint16_t n;    /* observations (saturating) */
    uint8_t off;   /* 1: the correction is disabled for this pair */
} nn_pair_stat_t;

typedef struct {
    nn_pair_stat_t pair[NN_MON_ANCHORS][NN_MON_ANCHORS]; /* [a][b]; TWR uses [a][a] */
    uint32_t disabled;                                   /* pairs switched off since power-up (STATS) */
} nn_monitor_t;

/* Forget every pair's history and enable all (a new flight); the counter is kept. */
void nn_monitor_reset(nn_monitor_t *m);

/* 1 if the correction may be applied to pair (a, b) (ids < NN_MON_ANCHORS). */
int nn_monitor_enabled(const nn_monitor_t *m, uint8_t a, uint8_t b);

/* One corrected measurement of pair (a, b): innovation y with the correction, the bias it subtracted and
 * the innovation variance S. Returns 1 if this observation switched the pair off. */
int nn_monitor_observe(nn_monitor_t *m, uint8_t a, uint8_t b, float y, float bias, float S);

#endif
