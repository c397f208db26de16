"""Build LPS anchor payloads as they go over the air (the inverse of harness/twin/lps_packets.py).

TDoA2 `rangePacket2` (57 B, + 14 B LPP position = 71 B) and TDoA3 header + remote entries (+ LPP):
byte layouts of ../shared/reference/crazyflie-estimator-and-lps.md 4.4, 4.5, 4.7.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from harness.errors import InputError

TYPE_TDOA2 = 0x22
TYPE_TDOA3 = 0x30
ANCHOR_ADDR_BASE = 0xBCCF000000000000
PAYLOAD_MAX = 128


@dataclass(frozen=True)
class RemoteInfo:
    """What an anchor reports about another: the last packet it received from it, and its ToF."""

    id: int
    seq: int          # 7 bits
    rx_ts: int        # sender clock, low 32 bits
    tof: int = 0      # ticks incl. antenna delay, 0 = unknown / not sent


def lpp_position(pos: tuple[float, float, float] | None) -> bytes:
    if pos is None:
        return b""
    return bytes([0xF0, 0x01]) + struct.pack("<3f", *pos)


def tdoa2_payload(sender: int, seq: int, tx_ts: int, remotes: list[RemoteInfo],
                  pos: tuple[float, float, float] | None) -> bytes:
    if not 0 <= sender < 8:
        raise InputError(f"TDoA2 anchor ids are 0..7, got {sender}")
    seqs = [0] * 8
    ts = [0] * 8
    tofs = [0] * 8
    seqs[sender], ts[sender] = seq & 0x7F, tx_ts & 0xFFFFFFFF
    for r in remotes:
        if not 0 <= r.id < 8 or r.id == sender:
            raise InputError(f"TDoA2 remote id {r.id} invalid for sender {sender}")
        seqs[r.id], ts[r.id], tofs[r.id] = r.seq & 0x7F, r.rx_ts & 0xFFFFFFFF, r.tof & 0xFFFF
    return (bytes([TYPE_TDOA2]) + bytes(seqs) + struct.pack("<8I", *ts) + struct.pack("<8H", *tofs)
            + lpp_position(pos))


def tdoa3_payload(seq: int, tx_ts: int, remotes: list[RemoteInfo], pos: tuple[float, float, float] | None,
                  with_tof: list[bool] | None = None) -> bytes:
    """with_tof[k]: send remote k as a full entry (with its ToF) or a short one."""
    if len(remotes) > 8:
        raise InputError("TDoA3 carries at most 8 remote entries")
    out = bytearray([TYPE_TDOA3, seq & 0x7F]) + struct.pack("<I", tx_ts & 0xFFFFFFFF) + bytes([len(remotes)])
    for k, r in enumerate(remotes):
        full = (with_tof[k] if with_tof is not None else True) and r.tof != 0
        out += bytes([r.id & 0xFF, (r.seq & 0x7F) | (0x80 if full else 0)]) + struct.pack("<I", r.rx_ts & 0xFFFFFFFF)
        if full:
            out += struct.pack("<H", r.tof & 0xFFFF)
    out += lpp_position(pos)
    if len(out) > PAYLOAD_MAX:
        raise InputError(f"TDoA3 payload of {len(out)} bytes exceeds {PAYLOAD_MAX}")
    return bytes(out)
