/* The per-measurement pipeline the firmware app calls: time rules, prediction, measurement model,
 * bias network, kinematic and chi-square gates, Joseph update, finalize, divergence guard.
 * docs/ARCHITECTURE.md is the contract; harness/twin/estimator.py is the numpy twin. */
#ifndef UWB_ESTIMATOR_H
#define UWB_ESTIMATOR_H

#include <stdint.h>

#include "bias_nn.h"
#include "bias_states.h"
#include "ekf_core.h"
#include "estimator_config.h" /* estimator_config_t, its defaults and checks: generated from messages.toml */
#include "gate_kinematic.h"
#include "nn_monitor.h"
#include "takeoff.h"

#define ESTIMATOR_MAX_ANCHORS 16          /* slots of the anchor table: any uint8 id, keyed by id */
#define ESTIMATOR_RADIO_POS_VALID_MS 2000u /* a position received over the radio (LPP) expires [ms] */

/* Who set a slot's position: the host (ANCHOR: stays) or the radio (LPP: valid 2 s after it was received). */
enum { EST_ANCHOR_FREE = 0, EST_ANCHOR_HOST = 1, EST_ANCHOR_RADIO = 2 };

/* Return codes (numerically equal to protocol enum error_code). */
enum {
    EST_OK = 0,
    EST_ERR_UNKNOWN_KIND = 1,  /* no row in the kinds table (mm_kinds.h); error_code UNKNOWN_TYPE */
    EST_ERR_UNKNOWN_ANCHOR = 4,
    EST_ERR_TIME_BACKWARDS = 5,
    EST_ERR_BAD_ANCHOR_ID = 7,
    EST_ERR_BAD_VALUE = 11
};

/* Supervisor events (= protocol enum result_flag), collected until the next result. */
enum {
    EST_FLAG_DIVERGED = 1,
    EST_FLAG_NON_FINITE = 2,
    EST_FLAG_OUT_OF_BOX = 4,
    EST_FLAG_SPEED = 8,
    EST_FLAG_COVARIANCE = 16,
    EST_FLAG_HEIGHT_FUSED = 32,
    EST_FLAG_NN_PAIR_OFF = 64, /* the pair monitor switched the correction off for this pair */
    EST_FLAG_GAP_RESTART = 128 /* restart after a measurement gap: not a divergence (estimator.c) */
};

/* Measurement statuses (= protocol enum status). */
enum {
    EST_ACCEPTED = 0,
    EST_REJECTED_KINEMATIC = 1,
    EST_REJECTED_CHI2 = 2,
    EST_REJECTED_GEOMETRY = 3,
    EST_REJECTED_BASELINE = 4   /* TDoA: |diff| >= distance between its anchors (always on) */
};

/* Modes and stage bits (= protocol enums ekf_mode, stage). */
/* EST_MODE_IMU_THRUST: IMU mode for a quadrotor, the horizontal specific force taken as zero (estimator.c). */
enum { EST_MODE_IMU = 0, EST_MODE_UWB_ONLY = 1, EST_MODE_IMU_THRUST = 2 };

/* The IMU tells when the vehicle sits on the floor (takeoff.h): the quadrotor model, or CONFIG floor_imu. */
static inline int estimator_floor_from_imu(const estimator_config_t *cfg)
{
    return cfg->mode == EST_MODE_IMU_THRUST || cfg->floor_imu;
}
enum {
    EST_STAGE_BIAS_NN = 1,
    EST_STAGE_KINEMATIC_GATE = 2,
    EST_STAGE_CHI2_GATE = 4,
    EST_STAGE_NN_STD = 8,       /* measurement std = the network's predicted std when it runs */
    EST_STAGE_ROBUST_UPDATE = 16, /* M-estimation weights on the update (robust_update.h) */
    EST_STAGE_NN_MONITOR = 32,    /* per-pair monitor of the corrections (nn_monitor.h) */
    EST_STAGE_BIAS_STATES = 64    /* per-anchor Gauss-Markov bias states on top of the network (bias_states.h) */
};
/* The paper's outlier rejection + network (the power-up default). */
#define EST_STAGES_ALL (EST_STAGE_BIAS_NN | EST_STAGE_KINEMATIC_GATE | EST_STAGE_CHI2_GATE)

typedef struct {
    uint8_t status;        /* EST_ACCEPTED / EST_REJECTED_* */
    float innovation;      /* y = z - bias - h(x), before the update (0 for geometry) */
    float innovation_var;  /* S = H P H^T + R (0 for geometry) */
    float bias;            /* what was subtracted [m]: the network's correction, plus the link's bias
                            * states with BIAS_STATES */
    float d_max;           /* kinematic bound, computed whether the gate is on or not */
    float gain[3];         /* K position rows, 0 unless accepted */
    /* platform_cost_now() units. cost_update includes the measurement model and finalize;
     * cost_predict: IMU predictions since the previous result, or (UWB-only) this measurement's
     * constant-velocity prediction. */
    uint32_t cost_nn, cost_gates, cost_update, cost_predict;
    uint8_t flags;         /* EST_FLAG_* events since the previous result */
} estimator_result_t;

typedef struct {
    estimator_config_t cfg;
    ekf_t ekf;
    float anchors[ESTIMATOR_MAX_ANCHORS][3];   /* by slot */
    uint8_t anchor_id[ESTIMATOR_MAX_ANCHORS];  /* the id a slot holds */
    uint8_t anchor_src[ESTIMATOR_MAX_ANCHORS]; /* EST_ANCHOR_* */
    uint32_t anchor_ms[ESTIMATOR_MAX_ANCHORS]; /* radio positions: when received (tag time, ms) */
    uint16_t anchor_known;            /* bit i: slot i holds an anchor */
    const bias_model_t *model;        /* may be NULL, or have NULL networks */
    uint64_t t_imu_us, t_uwb_us;      /* last accepted IMU / UWB timestamps (time rule) */
    uint8_t has_imu_time, has_uwb_time;
    gate_kinematic_t kin;             /* the kinematic gate's state (reset with the filter) */
    float box_min[3], box_max[3];     /* bounding box of the known anchors (supervisor) */
    uint64_t t_height_us;             /* last HEIGHT pseudo-measurement (time rule) */
    uint8_t has_height_time;
    uint8_t flags;                    /* EST_FLAG_* since the last result */
    nn_monitor_t nnmon;               /* per-pair monitor of the network's corrections (reset with the filter) */
    bias_states_t bstates;            /* per-anchor bias states (BIAS_STATES; reset with the filter) */
    takeoff_t takeoff;                /* IMU_THRUST or floor_imu: on the floor until the climb, after a touchdown */
    float last_good_pos[3];           /* re-initialisation point of the supervisor */
    uint32_t cost_predict;            /* cost of the predictions since the last measurement */
    uint32_t predictions;             /* IMU or CV predictions since power-up */
    uint32_t imu_ignored;             /* IMU samples counted and ignored in UWB-only mode */
    uint32_t divergences;             /* times the supervisor re-initialised the filter (not after gaps) */
    uint32_t gap_restarts;            /* restarts after a measurement gap (EST_FLAG_GAP_RESTART) */
    uint32_t heights;                 /* HEIGHT pseudo-measurements fused */
    uint32_t baseline_rejects;        /* TDoA measurements answered EST_REJECTED_BASELINE */
} estimator_t;

/* Default config, filter at its init position, no anchors, counters zero. */
void estimator_init(estimator_t *est, const bias_model_t *model);

/* cfg must be valid. reset != 0 re-initialises the filter at cfg's init position and forgets the
 * time references (a new flight may restart its clock); anchors and counters are kept. Changing
 * the mode should be done with reset. */
void estimator_configure(estimator_t *est, const estimator_config_t *cfg, int reset);

/* A position configured by the host (it stays). Any id; a new id takes a free slot, else the radio
 * position received longest ago; EST_ERR_BAD_ANCHOR_ID if every slot holds a host position. */
int estimator_set_anchor(estimator_t *est, uint8_t id, const float pos[3]);

/* A position received over the radio at t_us (LPP): valid ESTIMATOR_RADIO_POS_VALID_MS, refreshed by
 * every packet. A host position of the same id stays (nothing changes, EST_OK). A new id takes a free
 * slot, else the radio position received longest ago; EST_ERR_BAD_ANCHOR_ID if none is left. */
int estimator_set_radio_anchor(estimator_t *est, uint8_t id, const float pos[3], uint64_t t_us);

/* The position of anchor id valid at t_us (host: always; radio: within 2 s), or NULL; its slot, or -1
 * (the per-anchor state of the gates, the pair monitor and the bias states is kept by slot). */
const float *estimator_anchor(const estimator_t *est, uint8_t id, uint64_t t_us);
int estimator_anchor_slot(const estimator_t *est, uint8_t id, uint64_t t_us);

/* Inputs are finite (checked by the caller). EST_ERR_TIME_BACKWARDS (nothing changes) if t_us is
 * before the previous IMU sample. */
int estimator_on_imu(estimator_t *est, uint64_t t_us, const float acc[3], const float gyro[3]);

/* One measurement of any kind (enum meas_kind, a row of mm_kinds.h) through the pipeline: anchor_ids holds
 * as many ids as the kind names (A, B); *out is filled when EST_OK is returned. EST_ERR_UNKNOWN_KIND,
 * EST_ERR_UNKNOWN_ANCHOR / EST_ERR_TIME_BACKWARDS (before the previous measurement): nothing changes. */
int estimator_on_meas(estimator_t *est, uint8_t kind, uint64_t t_us, const uint8_t anchor_ids[2], float z,
                      estimator_result_t *out);

/* The same for a TWR range and a TDoA difference diff = d(tag, B) - d(tag, A). */
int estimator_on_twr(estimator_t *est, uint64_t t_us, uint8_t anchor, float range,
                     estimator_result_t *out);
int estimator_on_tdoa(estimator_t *est, uint64_t t_us, uint8_t anchor_a, uint8_t anchor_b, float diff,
                      estimator_result_t *out);

/* A height pseudo-measurement z [m] with standard deviation std (in (0, 1000] m, else EST_ERR_BAD_VALUE):
 * UWB-only mode predicts to t_us first; fused as a scalar update of z without gates. Does not count
 * as a fused UWB measurement for the kinematic gate. EST_ERR_TIME_BACKWARDS if t_us is before the
 * previous HEIGHT. */
int estimator_on_height(estimator_t *est, uint64_t t_us, float z, float std);

/* Position, world velocity, attitude (w, x, y, z), covariance diagonal (any pointer may be NULL). */
void estimator_state(const estimator_t *est, float pos[3], float vel_world[3], float quat[4],
                     float var[9]);

/* Predictions run since power-up (STATS.predictions). */
uint32_t estimator_prediction_count(const estimator_t *est);

#endif
