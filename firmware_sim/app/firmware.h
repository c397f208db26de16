/* The firmware application: bytes in -> frames -> estimator -> frames out. Platform independent:
 * the platform supplies a write callback and feeds received bytes; no OS calls, no allocation. */
#ifndef UWB_FIRMWARE_H
#define UWB_FIRMWARE_H

#include <stddef.h>
#include <stdint.h>

#include "controller.h"
#include "estimator.h"
#include "frame_rx.h"
#include "mm_table.h"
#include "tdoa_engine.h"
#include "uwb_msgs.h"

#define FW_VERSION_MAJOR 0
#define FW_VERSION_MINOR 1
#define FW_VERSION_PATCH 0

typedef void (*fw_write_fn)(void *ctx, const uint8_t *data, size_t n);

/* Every received byte or frame that was not used is counted in exactly one of these. */
typedef struct {
    uint32_t frames_ok, crc_errors, framing_errors, unknown_types, bad_lengths, non_finite,
        unknown_anchors, time_backwards, bad_configs, dropped_meas, imu_samples, results, predictions, seq_gaps,
        bad_values;
    uint32_t meas[MM_KIND_END]; /* measurement frames by kind (enum meas_kind; 0: none) */
    /* RADIO frames: handed to the engine, measurements formed, and every packet that formed none by
     * reason (protocol enum drop_reason; no_position also counts BAD_ANCHOR). */
    uint32_t radio_packets, radio_meas, radio_no_reference, radio_clock, radio_expired, radio_malformed,
        radio_unknown_type, radio_no_position;
} fw_stats_t;

typedef struct {
    estimator_t est;
    controller_t ctl;         /* closed loop: SETPOINT -> CONTROL */
    tdoa_engine_t tdoa;       /* RADIO: anchor packets -> TDoA measurements */
    frame_rx_t rx;
    fw_stats_t stats;
    uint16_t tx_seq;
    uint16_t next_rx_seq;
    uint8_t rx_seq_valid;
    fw_write_fn write;
    void *write_ctx;
    char target[8];
} firmware_t;

/* target: short platform name reported in HELLO_REPLY ("host", "stm32f405"). */
void firmware_init(firmware_t *fw, fw_write_fn write, void *write_ctx, const char *target);
void firmware_feed(firmware_t *fw, const uint8_t *data, size_t n);

#endif
