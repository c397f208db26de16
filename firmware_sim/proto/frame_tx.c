#include "frame_tx.h"

#include "cobs.h"

typedef char uwb_body_fits_one_cobs_block[UWB_MAX_BODY <= 253u ? 1 : -1]; /* cobs_encode_inplace's limit */

size_t uwb_frame_encode(const uwb_msg_t *msg, uint8_t *out)
{
    size_t n = uwb_body_encode(msg, out + 1); /* body at out[1..n], the COBS code byte goes in front */
    n = cobs_encode_inplace(out, n);
    out[n] = 0;
    return n + 1u;
}
