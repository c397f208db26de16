"""Twin of firmware_sim/core/tdoa_engine.c: the tag's TDoA engine (float64, Python integers for the
32/40-bit tick arithmetic). Same storage, eviction, bucket rule and matching order as the C, so both
form the same measurements from the same packets (tests/unit/test_tdoa_engine.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

from harness.twin.lps_packets import Packet, Remote

STORAGE_COUNT = 16
TOF_PER_ANCHOR = 8
TS_FREQ = 63.8976e9
SPEED_OF_LIGHT = 299792458.0
CC_ACCEPTED_NOISE = 0.03e-6
CC_MAX_DEVIATION = 20e-6
CC_FILTER = 0.1
CC_BUCKET_MAX = 4
REMOTE_VALID_US = 60_000
TOF_VALID_US = 2_000_000
MASK32 = 0xFFFFFFFF
MASK40 = 0xFFFFFFFFFF
# Modulo rather than a mask: the same for integer ticks (the C), and it also takes the simulator's unrounded
# timestamps (RadioConfig.exact_stamps), which separate the clock correction's error from the tick's.
WRAP32 = 1 << 32
WRAP40 = 1 << 40
METRES_PER_TICK = SPEED_OF_LIGHT / TS_FREQ

MEASUREMENT, DROP_NO_REFERENCE, DROP_CLOCK, DROP_EXPIRED, DROP_MALFORMED, DROP_UNKNOWN_TYPE = range(6)


@dataclass
class TofEntry:
    id: int
    tof: float      # integer ticks; float only for unrounded analysis stamps (as rx_ts below)
    t_us: int


@dataclass
class AnchorCtx:
    id: int
    has_last: bool = False
    seq: int = 0
    rx_ts: float = 0
    tx_ts: float = 0
    rx_t_us: int = 0
    cc: float = 0.0
    bucket: int = 0
    packets: int = 0
    tof: list[TofEntry | None] = field(default_factory=lambda: [None] * TOF_PER_ANCHOR)

    def lookup_tof(self, remote: int) -> TofEntry | None:
        return next((t for t in self.tof if t is not None and t.id == remote), None)

    def tof_slot(self, remote: int) -> int:
        for k, t in enumerate(self.tof):
            if t is not None and t.id == remote:
                return k
        for k, t in enumerate(self.tof):
            if t is None:
                return k
        return min(range(TOF_PER_ANCHOR), key=lambda k: (self.tof[k].t_us, k))  # type: ignore[union-attr]

    def clock_update(self, rx_ts: float, tx_ts: float) -> bool:
        """The bucket rule; True if this sample is reliable."""
        if not self.has_last:
            return False
        drx = (rx_ts - self.rx_ts) % WRAP32
        dtx = (tx_ts - self.tx_ts) % WRAP32
        if dtx == 0:
            return False
        cand = drx / dtx
        dev = cand - self.cc
        if -CC_ACCEPTED_NOISE < dev < CC_ACCEPTED_NOISE:
            self.cc = CC_FILTER * self.cc + (1.0 - CC_FILTER) * cand
            self.bucket = min(self.bucket + 1, CC_BUCKET_MAX)
            return True
        if self.bucket == 0:
            if 1.0 - CC_MAX_DEVIATION < cand < 1.0 + CC_MAX_DEVIATION:
                self.cc = cand
        else:
            self.bucket -= 1
        return False


@dataclass(frozen=True)
class Measurement:
    anchor_a: int   # reference Ar
    anchor_b: int   # sender An
    diff: float     # d(tag, B) - d(tag, A) [m]


class TdoaEngine:
    def __init__(self) -> None:
        self.slots: list[AnchorCtx | None] = [None] * STORAGE_COUNT

    def anchor(self, anchor_id: int) -> AnchorCtx | None:
        return next((a for a in self.slots if a is not None and a.id == anchor_id), None)

    def _get_or_create(self, anchor_id: int) -> AnchorCtx:
        a = self.anchor(anchor_id)
        if a is not None:
            return a
        free = [k for k, s in enumerate(self.slots) if s is None]
        if free:
            k = free[0]
        else:
            k = min(range(STORAGE_COUNT), key=lambda i: (self.slots[i].rx_t_us, i))  # type: ignore[union-attr]
        ctx = AnchorCtx(id=anchor_id)
        self.slots[k] = ctx
        return ctx

    def _candidate(self, an: AnchorCtx, r: Remote, t_us: int) -> tuple[int, AnchorCtx | None, TofEntry | None]:
        ar = self.anchor(r.id)
        tof = an.lookup_tof(r.id)
        if ar is None or not ar.has_last or ar.seq != r.seq or tof is None:
            return DROP_NO_REFERENCE, None, None
        if _age(t_us, ar.rx_t_us) > REMOTE_VALID_US or _age(t_us, tof.t_us) > TOF_VALID_US:
            return DROP_EXPIRED, None, None
        return 0, ar, tof

    def _match(self, an: AnchorCtx, pkt: Packet, t_us: int) -> tuple[int, Remote | None, AnchorCtx | None,
                                                                       TofEntry | None]:
        """The candidate the tag heard most recently (first in packet order on ties), TDoA2 and TDoA3."""
        reason = DROP_NO_REFERENCE
        best: tuple[Remote, AnchorCtx, TofEntry] | None = None
        for r in pkt.remote:
            why, ar, tof = self._candidate(an, r, t_us)
            if why:
                if why == DROP_EXPIRED:
                    reason = why
                continue
            assert ar is not None and tof is not None
            if best is None or ar.rx_t_us > best[1].rx_t_us:
                best = (r, ar, tof)
        if best is None:
            return reason, None, None, None
        return MEASUREMENT, *best

    def process(self, pkt: Packet, sender: int, rx_ts: float, t_us: int) -> tuple[int, Measurement | None]:
        """One parsed packet: (MEASUREMENT, measurement) or (DROP_*, None); the state is updated either way.
        Timestamps are integer ticks as on the wire, or float ticks (analysis of unrounded stamps)."""
        an = self._get_or_create(sender)
        rx_ts %= WRAP40
        an.packets = (an.packets + 1) & MASK32
        for r in pkt.remote:
            if r.has_tof:
                an.tof[an.tof_slot(r.id)] = TofEntry(r.id, r.tof, t_us)
        rc, meas = DROP_CLOCK, None
        if an.clock_update(rx_ts, pkt.tx_ts) and an.cc > 0.0:
            rc, rm, ar, tof = self._match(an, pkt, t_us)
            if rc == MEASUREMENT:
                assert rm is not None and ar is not None and tof is not None
                drx = (rx_ts - ar.rx_ts) % WRAP32
                dtx = (pkt.tx_ts - rm.rx_ts) % WRAP32
                ticks = float(drx) - (float(tof.tof) + float(dtx)) * an.cc
                meas = Measurement(ar.id, sender, ticks * METRES_PER_TICK)
        an.has_last, an.seq, an.rx_ts, an.tx_ts, an.rx_t_us = True, pkt.seq, rx_ts, pkt.tx_ts, t_us
        return rc, meas


def _age(now: int, then: int) -> int:
    return now - then if now >= then else 1 << 64


def sender_of(src_addr: int) -> int:
    return int(src_addr) & 0xFF


def replay(t_us: list[int], rx_ts: list[int], src_addr: list[int], payloads: list[bytes],
           engine: TdoaEngine | None = None) -> tuple[TdoaEngine, list[tuple[int, Measurement | None]]]:
    """Parse and process a packet sequence as the firmware does: (engine, [(outcome, measurement)]).
    Outcomes are protocol drop_reason values (MEASUREMENT = 0); rx_ts beyond 40 bits is malformed."""
    from harness.twin import lps_packets as lp
    eng = engine if engine is not None else TdoaEngine()
    out: list[tuple[int, Measurement | None]] = []
    for t, rx, src, payload in zip(t_us, rx_ts, src_addr, payloads):
        sender = sender_of(src)
        if int(rx) >> 40:
            out.append((DROP_MALFORMED, None))
            continue
        rc, pkt = lp.parse(payload, sender)
        if rc != lp.OK:
            out.append((DROP_UNKNOWN_TYPE if rc == lp.ERR_UNKNOWN_TYPE else DROP_MALFORMED, None))
            continue
        out.append(eng.process(pkt, sender, int(rx), int(t)))
    return eng, out
