"""Test oracle: the TDoA tag rules of Bitcraze's crazyflie-firmware (release 2026.08: tdoaEngine.c,
tdoaStorage.c, clockCorrectionEngine.c, lpsTdoa2Tag.c, lpsTdoa3Tag.c) re-stated from their documented
behaviour, independently of harness/twin/tdoa_engine.py (its own parsing, storage as lists of records, its
own loops; no code of theirs). tests/unit/test_bitcraze_parity.py checks that the firmware and the twin
form the same pairs, whole ticks and counts as this oracle.

The rules, as a Crazyflie's tag applies them to one received packet (time in whole ms of tag time):
1. the sender's context: found by id, else created in the first free of 16 slots, else in the one
   updated longest ago (strictly before now; slot 0 when none is);
2. every remote entry with a non-zero RX stamp is stored (first slot of that id, else the first slot
   expiring earliest; valid 30 ms), every non-zero ToF alike (valid 2 s);
3. clock correction, if the previous packet's stamps are both non-zero: candidate = (rx - rx')_32 /
   (tx - tx')_32 (-1 for a zero TX interval); within 0.03 ppm of the estimate -> filtered (0.1 old,
   0.9 new), bucket +1 (max 4), reliable; else bucket -1, or when empty a candidate within 20 ppm of 1
   becomes the estimate (not reliable);
4. if reliable and the estimate > 0: matching over the live stored entries in slot order.
   random: an engine-wide uint8 offset +1, then from index offset mod n on, the first entry whose anchor
   exists (looking it up creates it otherwise), whose seq is the tag's last from it, with a live ToF.
   youngest: the entry with a live ToF, an existing anchor, the latest update time (> 0, strictly later
   than earlier ones) and a matching seq;
5. tdoa = int64((rx - rx_Ar)_32 - (tof + (tx - rxAr_by_An)_32) cc), distance = c tdoa / f;
6. the sender's stamps, seq and update time are stored.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

F = 499.2e6 * 128
C = 299792458.0
M32 = (1 << 32) - 1
M40 = (1 << 40) - 1


@dataclass
class Info:
    id: int
    rx: int = 0
    tx: int = 0
    seq: int = 0
    updated: int = 0
    cc: float = 0.0
    bucket: int = 0
    # records [id, seq, rx, end_of_life] and [id, tof, end_of_life]; unused: id 0, end 0
    remote: list[list[int]] = field(default_factory=lambda: [[0, 0, 0, 0] for _ in range(16)])
    tofs: list[list[int]] = field(default_factory=lambda: [[0, 0, 0] for _ in range(16)])


def _first_or_earliest(records: list[list[int]], rid: int) -> list[int]:
    for rec in records:
        if rec[0] == rid:
            return rec
    return min(records, key=lambda rec: rec[-1])   # min() keeps the first of equal ones


def _lookup(records: list[list[int]], rid: int, now: int) -> list[int] | None:
    for rec in records:
        if rec[0] == rid:
            return rec if rec[-1] > now else None
    return None


def entries(payload: bytes, sender: int) -> tuple[int, int, list[tuple[int, int, int, int]]] | None:
    """(seq, tx, [(id, seq, rx, tof)]) of a TDoA2 / TDoA3 payload, None if not processed."""
    if payload[:1] == b"\x22" and len(payload) >= 57 and sender < 8:
        seqs, ts, tofs = payload[1:9], struct.unpack_from("<8I", payload, 9), struct.unpack_from("<8H", payload, 41)
        rem = [(i, seqs[i] & 0x7F, ts[i], tofs[i]) for i in range(8) if i != sender]
        return seqs[sender] & 0x7F, ts[sender], rem
    if payload[:1] == b"\x30" and len(payload) >= 7:
        out, at = [], 7
        for _ in range(payload[6]):
            size = 8 if at + 1 < len(payload) and payload[at + 1] & 0x80 else 6
            if at + size > len(payload):
                break
            rid, s, rx = payload[at], payload[at + 1], struct.unpack_from("<I", payload, at + 2)[0]
            if rid != sender:   # the firmware skips an anchor's entry about itself (real anchors send none)
                out.append((rid, s & 0x7F, rx, struct.unpack_from("<H", payload, at + 6)[0] if size == 8 else 0))
            at += size
        return payload[1] & 0x7F, struct.unpack_from("<I", payload, 2)[0], out
    return None


class Oracle:
    def __init__(self, algorithm: str) -> None:
        self.algorithm = algorithm          # "random" / "youngest"
        self.slots: list[Info | None] = [None] * 16
        self.offset = 0

    def _context(self, aid: int, now: int) -> tuple[Info, bool]:
        for s in self.slots:
            if s is not None and s.id == aid:
                return s, True
        free = [k for k, s in enumerate(self.slots) if s is None]
        if free:
            k = free[0]
        else:
            k, oldest = 0, now
            for j, s in enumerate(self.slots):
                if s is not None and s.updated < oldest:
                    k, oldest = j, s.updated
        if self.slots[k] is None:
            self.slots[k] = Info(aid)
        else:   # their storage is an array: whoever holds this slot now sees the new anchor's record
            self.slots[k].__dict__.update(Info(aid).__dict__)   # type: ignore[union-attr]
        return self.slots[k], False   # type: ignore[return-value]

    def _clock(self, an: Info, rx: int, tx: int) -> bool:
        if an.rx == 0 or an.tx == 0:
            return False
        dtx = (tx - an.tx) & M32
        cand = ((rx - an.rx) & M32) / dtx if dtx else -1.0
        if abs(cand - an.cc) < 0.03e-6:
            an.cc, an.bucket = an.cc * 0.1 + cand * 0.9, min(an.bucket + 1, 4)
            return True
        if an.bucket:
            an.bucket -= 1
        elif 1 - 20e-6 < cand < 1 + 20e-6:
            an.cc = cand
        return False

    def _usable(self, an: Info, rec: list[int], now: int) -> Info | None:
        other, existed = self._context(rec[0], now)
        tof = _lookup(an.tofs, rec[0], now)
        return other if existed and rec[1] == other.seq and tof is not None and tof[1] else None

    def _random(self, an: Info, now: int) -> tuple[Info, list[int]] | None:
        self.offset = (self.offset + 1) % 256
        live = [rec for rec in an.remote if rec[3] > now]
        for step in range(len(live)):
            rec = live[(self.offset + step) % len(live)]
            other = self._usable(an, rec, now)
            if other is not None:
                return other, rec
        return None

    def _youngest(self, an: Info, now: int) -> tuple[Info, list[int]] | None:
        best = None
        for rec in an.remote:
            tof = _lookup(an.tofs, rec[0], now)
            if rec[3] <= now or tof is None or not tof[1]:
                continue
            other, existed = self._context(rec[0], now)
            if existed and other.updated > (best[0].updated if best else 0) and rec[1] == other.seq:
                best = (other, rec)
        return best

    def packet(self, t_us: int, rx: int, sender: int, payload: bytes) -> tuple[int, int, int] | None:
        """(reference, sender, tdoa ticks) or None."""
        parsed = entries(payload, sender)
        if parsed is None:
            return None
        seq, tx, remotes = parsed
        now, rx = (t_us // 1000) & M32, rx & M40
        an, _ = self._context(sender, now)
        for rid, rseq, rrx, tof in remotes:
            if rrx:
                _first_or_earliest(an.remote, rid)[:] = [rid, rseq, rrx, now + 30]
            if tof:
                _first_or_earliest(an.tofs, rid)[:] = [rid, tof, now + 2000]
        result = None
        if self._clock(an, rx, tx) and an.cc > 0:
            found = self._random(an, now) if self.algorithm == "random" else self._youngest(an, now)
            if found is not None:
                other, _ = found   # their calcTDoA reads ToF and rx_Ar_by_An from the storage as it is now (0 if gone)
                tof, rem = _lookup(an.tofs, other.id, now), _lookup(an.remote, other.id, now)
                ticks = int(((rx - other.rx) & M32) - ((tof[1] if tof else 0) + ((tx - (rem[2] if rem else 0)) & M32)) * an.cc)
                result = (other.id, sender, ticks)
        an.rx, an.tx, an.seq, an.updated = rx, tx, seq, now
        return result


def metres(ticks: int) -> float:
    return C * ticks / F
