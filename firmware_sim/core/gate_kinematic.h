/* Kinematic ("model-based") outlier gate of the paper: the innovation cannot exceed how far the
 * tag can have moved since the reference time, d_max = |v| dt + a_max dt^2 / 2. The gate keeps its own
 * state (gate_kinematic_t): when measurements were last fused, so that its window widens while they are
 * rejected (docs/ARCHITECTURE.md, pipeline step 3). harness/twin/gates.py KinematicGate is the twin. */
#ifndef UWB_GATE_KINEMATIC_H
#define UWB_GATE_KINEMATIC_H

#include <stdint.h>

#define GATE_KIN_ANCHORS 16 /* = ESTIMATOR_MAX_ANCHORS */
/* A kind that names no anchor (a sensor: the ToF ranger) is its own link, in the slot after the anchors'. */
#define GATE_KIN_SENSOR GATE_KIN_ANCHORS
#define GATE_KIN_LINKS (GATE_KIN_ANCHORS + 1)

typedef struct {
    uint64_t t_fused_us; /* last UWB measurement fused into the filter */
    uint8_t has_fused;   /* 0 until the first fusion after a reset */
    /* Per anchor (and the sensor slot GATE_KIN_SENSOR): when it was last measured and last took part in a
     * fused measurement. Their gap is how long its links have been rejected; the window widens by it. */
    uint64_t t_anchor_seen_us[GATE_KIN_LINKS];
    uint64_t t_anchor_fused_us[GATE_KIN_LINKS];
    /* Set by gate_kinematic_window for its measurement: how long the links of its anchors (the longer of
     * the two) had been rejected up to their previous measurement; the chi-square gate re-opens on it. */
    int64_t rejected_us;
} gate_kinematic_t;

/* Nothing fused yet (a new flight: the filter was reset). */
void gate_kinematic_reset(gate_kinematic_t *g);

/* The gate's dt [s] for a measurement at t_us between anchors id_a and id_b (TWR: id_b = id_a; ids <
 * GATE_KIN_ANCHORS; a kind without anchors: both GATE_KIN_SENSOR): from the filter's reference time t_ref (have_ref = 0: none yet, then dt_min) or the
 * last fusion, whichever is older, plus how long these anchors had been rejected (also left in
 * g->rejected_us); at least dt_min. Marks the anchors as measured at t_us. widen = 0: the nominal window only
 * (no widening, rejected_us = 0, so the chi-square guard does not re-open either): a vehicle on the floor. */
float gate_kinematic_window(gate_kinematic_t *g, uint64_t t_us, uint8_t id_a, uint8_t id_b, uint64_t t_ref,
                            int have_ref, float dt_min, int widen);

/* The measurement at t_us between id_a and id_b was fused into the filter. A sensor's (GATE_KIN_SENSOR) is
 * not a UWB measurement: it sets only its own link's time, not t_fused_us. */
void gate_kinematic_fused(gate_kinematic_t *g, uint64_t t_us, uint8_t id_a, uint8_t id_b);

/* dt [s] = max(t_meas - t_ref, dt_min); have_ref = 0 (no reference time yet) gives dt_min. */
float gate_kinematic_dt(int64_t dt_us, int have_ref, float dt_min);

/* d_max [m] for velocity v (any frame: only its norm is used), dt [s] and a_max [m/s^2]. */
float gate_kinematic_dmax(const float v[3], float dt, float a_max);

/* 1 if |innovation| <= factor * d_max (factor 1 for TWR, 2 for TDoA: two ranges differ). */
int gate_kinematic_pass(float innovation, float d_max, float factor);

#endif
