"""Twin of firmware_sim/core/lps_packets.c: parse an LPS anchor payload (TDoA2 / TDoA3 + optional LPP).

Same checks, same outcome for every byte sequence (tests feed both the same payloads). Byte layouts:
../shared/reference/crazyflie-estimator-and-lps.md 4.4, 4.5, 4.7. Tolerant as a Crazyflie's tag: only an
incomplete header (or a TDoA2 sender id > 7) is malformed; the remote entries that fit are used (an entry
naming the sender is skipped), other trailing bytes are ignored unless they are a complete LPP position.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

TYPE_TDOA2 = 0x22
TYPE_TDOA3 = 0x30
LPP_SHORT = 0xF0
LPP_POSITION = 0x01
TDOA2_SIZE = 57
TDOA2_ANCHORS = 8
TDOA3_HEADER = 7
MAX_REMOTE = 20     # entries one 128-byte payload can carry
SEQ_MASK = 0x7F
MAX_COORD = 1000.0

OK, ERR_MALFORMED, ERR_UNKNOWN_TYPE = 0, 1, 2


@dataclass(frozen=True)
class Remote:
    id: int
    seq: int
    tof: float      # ticks, 0 = none; integer as parsed, float only in the simulator's unrounded analysis packets
    rx_ts: float    # 0 = not heard


@dataclass
class Packet:
    type: int
    seq: int = 0
    tx_ts: float = 0
    remote: list[Remote] = field(default_factory=list)
    pos: tuple[float, float, float] | None = None


def _f32(b: bytes) -> float:
    return float(struct.unpack("<f", b)[0])


def _lpp(p: bytes, pkt: Packet) -> None:
    if len(p) < 14 or p[0] != LPP_SHORT or p[1] != LPP_POSITION:
        return
    xyz = tuple(_f32(p[2 + 4 * k:6 + 4 * k]) for k in range(3))
    if all(math.isfinite(v) and -MAX_COORD <= v <= MAX_COORD for v in xyz):
        pkt.pos = (xyz[0], xyz[1], xyz[2])


def _tdoa2(p: bytes, sender: int, pkt: Packet) -> int:
    if len(p) < TDOA2_SIZE or sender >= TDOA2_ANCHORS:
        return ERR_MALFORMED
    seqs = p[1:9]
    ts = struct.unpack_from("<8I", p, 9)
    tofs = struct.unpack_from("<8H", p, 41)
    pkt.seq = seqs[sender] & SEQ_MASK
    pkt.tx_ts = ts[sender]
    pkt.remote = [Remote(i, seqs[i] & SEQ_MASK, tofs[i], ts[i]) for i in range(TDOA2_ANCHORS) if i != sender]
    _lpp(p[TDOA2_SIZE:], pkt)
    return OK


def _tdoa3(p: bytes, sender: int, pkt: Packet) -> int:
    if len(p) < TDOA3_HEADER:
        return ERR_MALFORMED
    pkt.seq = p[1] & SEQ_MASK
    pkt.tx_ts = struct.unpack_from("<I", p, 2)[0]
    off = TDOA3_HEADER
    for _ in range(p[6]):
        if len(p) - off < 6:
            return OK
        rid, s = p[off], p[off + 1]
        need = 8 if s >> 7 else 6
        if len(p) - off < need:
            return OK
        if rid != sender and len(pkt.remote) < MAX_REMOTE:
            tof = struct.unpack_from("<H", p, off + 6)[0] if need == 8 else 0
            pkt.remote.append(Remote(rid, s & SEQ_MASK, tof, struct.unpack_from("<I", p, off + 2)[0]))
        off += need
    _lpp(p[off:], pkt)
    return OK


def parse(payload: bytes, sender: int) -> tuple[int, Packet]:
    """(OK, packet) or (ERR_MALFORMED / ERR_UNKNOWN_TYPE, partial packet)."""
    if len(payload) == 0:
        return ERR_MALFORMED, Packet(type=0)
    pkt = Packet(type=payload[0])
    if payload[0] == TYPE_TDOA2:
        return _tdoa2(payload, sender, pkt), pkt
    if payload[0] == TYPE_TDOA3:
        return _tdoa3(payload, sender, pkt), pkt
    return ERR_UNKNOWN_TYPE, pkt
