/* What the firmware's frame handlers share across app/ (firmware.c dispatches; fw_radio.c, fw_control.c
 * handle their frames). Not part of the firmware's interface (firmware.h). */
#ifndef UWB_FW_INTERNAL_H
#define UWB_FW_INTERNAL_H

#include <stdint.h>

#include "firmware.h"

/* Encode, frame and write one message (its seq is the next tx_seq). */
void fw_send_msg(firmware_t *fw, uwb_msg_t *msg);
/* ERROR code about the frame `bad`. */
void fw_send_error(firmware_t *fw, uint8_t code, const uwb_msg_t *bad, uint32_t detail);
/* RESULT of the measurement frame `in` with the estimator's result and the compute it took. */
void fw_send_result(firmware_t *fw, const uwb_msg_t *in, uint8_t kind, uint64_t t_us, const estimator_result_t *er,
                    uint32_t compute);
/* A measurement the estimator refused (rc): counted by reason, answered by ERROR. */
void fw_refuse_measurement(firmware_t *fw, const uwb_msg_t *in, int rc, uint32_t detail);

void fw_on_radio(firmware_t *fw, const uwb_msg_t *in);      /* fw_radio.c */
void fw_on_clock_req(firmware_t *fw, const uwb_msg_t *in);  /* fw_radio.c */
void fw_on_setpoint(firmware_t *fw, const uwb_msg_t *in);   /* fw_control.c */

#endif
