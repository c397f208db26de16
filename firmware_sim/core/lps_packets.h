/* Parsing of LPS anchor payloads as the tag's radio receives them (after the 21-byte MAC header):
 * TDoA2 rangePacket2 (57 B, 71 B with the LPP position), TDoA3 header + remote entries (+ optional LPP).
 * Byte layouts: ../shared/reference/crazyflie-estimator-and-lps.md 4.4, 4.5, 4.7. Every length and
 * field is checked: any byte sequence gives a packet or an error code, never an out-of-bounds read. */
#ifndef UWB_LPS_PACKETS_H
#define UWB_LPS_PACKETS_H

#include <stddef.h>
#include <stdint.h>

#define LPS_TYPE_TDOA2 0x22u
#define LPS_TYPE_TDOA3 0x30u
#define LPS_LPP_SHORT 0xF0u
#define LPS_LPP_POSITION 0x01u
#define LPS_TDOA2_SIZE 57u
#define LPS_TDOA2_ANCHORS 8u
#define LPS_TDOA3_HEADER 7u
#define LPS_MAX_REMOTE 8u
#define LPS_SEQ_MASK 0x7Fu
/* Anchor positions further than this from the origin are refused as implausible [m]. */
#define LPS_MAX_COORD 1000.0f

enum { LPS_OK = 0, LPS_ERR_MALFORMED = 1, LPS_ERR_UNKNOWN_TYPE = 2 };

typedef struct {
    uint8_t id;       /* remote anchor */
    uint8_t seq;      /* seq (7 bits) of the latest packet the sender received from it */
    uint8_t has_tof;
    uint16_t tof;     /* time of flight remote -> sender, sender clock ticks, antenna delay included */
    uint32_t rx_ts;   /* when the sender received that packet, sender clock, low 32 bits */
} lps_remote_t;

typedef struct {
    uint8_t type;     /* LPS_TYPE_TDOA2 / LPS_TYPE_TDOA3 */
    uint8_t seq;      /* this packet's seq, 7 bits */
    uint32_t tx_ts;   /* this packet's TX time, sender clock, low 32 bits */
    uint8_t n_remote;
    lps_remote_t remote[LPS_MAX_REMOTE];
    uint8_t has_pos;  /* an LPP ANCHOR_POSITION was appended */
    float pos[3];
} lps_packet_t;

/* sender: the anchor id (low byte of the MAC source address). TDoA2 senders must be 0..7. */
int lps_parse(const uint8_t *payload, size_t n, uint8_t sender, lps_packet_t *out);

#endif
