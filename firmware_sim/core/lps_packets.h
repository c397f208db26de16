/* Parsing of LPS anchor payloads as the tag's radio receives them (after the 21-byte MAC header):
 * TDoA2 rangePacket2 (57 B, 71 B with the LPP position), TDoA3 header + remote entries (+ optional LPP).
 * Byte layouts: ../shared/reference/crazyflie-estimator-and-lps.md 4.4, 4.5, 4.7. Every read is
 * bounds-checked: any byte sequence gives a packet or an error code, never an out-of-bounds read.
 * Tolerant as a Crazyflie's tag: a packet is refused only if its header is incomplete (TDoA2 < 57 B or
 * a sender id > 7, TDoA3 < 7 B); of the remote entries, those that fit are used (more than 8 is fine,
 * an entry naming the sender itself is skipped), bytes after them are ignored unless they are a
 * complete, finite LPP ANCHOR_POSITION. */
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
/* remote entries one 128-byte payload can carry (7 + 20 x 6 bytes) */
#define LPS_MAX_REMOTE 20u
#define LPS_SEQ_MASK 0x7Fu
/* Anchor positions further than this from the origin are refused as implausible [m]. */
#define LPS_MAX_COORD 1000.0f

enum { LPS_OK = 0, LPS_ERR_MALFORMED = 1, LPS_ERR_UNKNOWN_TYPE = 2 };

typedef struct {
    uint8_t id;       /* remote anchor */
    uint8_t seq;      /* seq (7 bits) of the latest packet the sender received from it */
    uint16_t tof;     /* time of flight remote -> sender, sender clock ticks, antenna delay included;
                       * 0 = none (TDoA3 short entry, or not ranged yet) */
    uint32_t rx_ts;   /* when the sender received that packet, sender clock, low 32 bits; 0 = not heard */
} lps_remote_t;

typedef struct {
    uint8_t type;     /* LPS_TYPE_TDOA2 / LPS_TYPE_TDOA3 */
    uint8_t seq;      /* this packet's seq, 7 bits */
    uint32_t tx_ts;   /* this packet's TX time, sender clock, low 32 bits */
    uint8_t n_remote;
    lps_remote_t remote[LPS_MAX_REMOTE];
    uint8_t has_pos;  /* a complete, finite LPP ANCHOR_POSITION within LPS_MAX_COORD was appended */
    float pos[3];
} lps_packet_t;

/* sender: the anchor id (low byte of the MAC source address). TDoA2 senders must be 0..7. */
int lps_parse(const uint8_t *payload, size_t n, uint8_t sender, lps_packet_t *out);

#endif
