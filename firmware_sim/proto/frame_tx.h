/* One message -> one frame on the wire, built in a single buffer (no body copy). */
#ifndef UWB_FRAME_TX_H
#define UWB_FRAME_TX_H

#include <stddef.h>
#include <stdint.h>

#include "uwb_msgs.h"

/* Encode msg as body + CRC, COBS and 0x00 delimiter into out (UWB_MAX_ENCODED + 1 bytes); returns the
 * length with the delimiter. The same bytes as uwb_body_encode + cobs_encode + 0x00, for every message. */
size_t uwb_frame_encode(const uwb_msg_t *msg, uint8_t *out);

#endif
