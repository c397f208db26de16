/* The measurement kinds: one const row per kind (docs/ARCHITECTURE.md "Adding a measurement kind"). A row
 * says how many anchors a measurement of its kind names, its model h(x) and H, which configuration fields
 * hold its std, chi-square threshold and kinematic bound, and which network corrects it. The estimator's
 * pipeline (estimator.c) reads only rows: it has no branch on a kind. The kind codes and the list of rows
 * (MM_KIND_ROWS) are generated from protocol/messages.toml (mm_table.h); kind NAME's row is
 * `mm_kind_<name>`, defined next to its model in core/mm_<name>.c, one file per measurement model. */
#ifndef UWB_MM_KINDS_H
#define UWB_MM_KINDS_H

#include <stddef.h>
#include <stdint.h>

#include "estimator_config.h"
#include "mm_table.h"

/* Below this tag-anchor distance [m] a direction (p - a)/|p - a| is undefined. */
#define MM_MIN_DISTANCE 1e-6f

/* Model outcomes: MM_DEGENERATE -> RESULT.status REJECTED_GEOMETRY, MM_OUT_OF_BASELINE -> REJECTED_BASELINE. */
enum { MM_OK = 0, MM_DEGENERATE = 1, MM_OUT_OF_BASELINE = 2 };

/* What a model may read: the estimate, the measurement's anchors (NULL beyond the kind's count), the
 * measured value and the configuration. */
typedef struct {
    const float *p;              /* estimated position [3] (of the body origin: the state) */
    const float (*R)[3];         /* estimated attitude, body -> world */
    const float *a, *b;          /* anchor positions [3] (NULL beyond the kind's count) */
    float z;                     /* the measurement */
    const estimator_config_t *cfg;
} mm_input_t;

/* Predicted measurement *h and the position part H[0..2] of its Jacobian; MM_OK or why not (then the
 * pipeline stops: *h and H are not used). */
typedef int (*mm_model_fn)(const mm_input_t *in, float *h, float H[3]);

/* The std [m] of one measurement when it depends on the measurement (mm_kind_t.std_of; NULL: the
 * configuration field std_off). */
typedef float (*mm_std_fn)(const mm_input_t *in);

/* No network corrects the kind (mm_kind_t.net). */
#define MM_NO_NET ((size_t)-1)

typedef struct {
    uint8_t kind;        /* enum meas_kind (MM_KIND_*) */
    uint8_t n_anchors;   /* anchor ids a measurement names: 0 (a sensor: its own link), 1 (A) or 2 (A, B) */
    mm_model_fn model;
    size_t std_off;      /* offsetof(estimator_config_t, ...) of its float std [m], */
    size_t chi2_off;     /* chi-square threshold, */
    size_t a_max_off;    /* and kinematic gate acceleration bound */
    float gate_factor;   /* the kinematic gate rejects |y| > gate_factor d_max */
    size_t net;          /* offsetof(bias_model_t, ...) of its network (bias_nn.h), or MM_NO_NET */
    mm_std_fn std_of;    /* NULL: the std is the field at std_off */
    float floor_below;   /* a range to the floor: below this [m] the vehicle sits on it (takeoff.h); 0: none */
} mm_kind_t;

#define MM_DECLARE_ROW(name) extern const mm_kind_t mm_kind_##name;
MM_KIND_ROWS(MM_DECLARE_ROW)

/* The row of a kind code, or NULL. */
const mm_kind_t *mm_kind(uint8_t kind);

/* A float field of the configuration named by a row's offset. */
float mm_cfg(const estimator_config_t *cfg, size_t off);

#endif
