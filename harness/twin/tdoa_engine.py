"""Twin of firmware_sim/core/tdoa_engine.c: the tag's TDoA engine (float64, Python integers for the
32/40-bit tick arithmetic; the C computes the clock correction in integers that give exactly these float64
values, firmware_sim/core/tdoa_clock.h). Same storage slots, expiry in whole ms, bucket rule, matching ("random": the
rotating start; "youngest") and whole-tick truncation as the C, so both form the same measurements from
the same packets (tests/unit/test_tdoa_engine.py); both form what a Crazyflie's tag forms (docs/radio.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

from harness.twin.lps_packets import TYPE_TDOA2, Packet

STORAGE_COUNT = 16
REMOTE_COUNT = 16
TOF_COUNT = 16
REMOTE_VALID_MS = 30
TOF_VALID_MS = 2000
TS_FREQ = 63.8976e9
SPEED_OF_LIGHT = 299792458.0
CC_ACCEPTED_NOISE = 0.03e-6
CC_MAX_DEVIATION = 20e-6
CC_FILTER = 0.1
CC_BUCKET_MAX = 4
MASK32 = 0xFFFFFFFF
MASK40 = 0xFFFFFFFFFF
# Modulo rather than a mask: the same for integer ticks (the C), and it also takes the simulator's unrounded
# timestamps (RadioConfig.exact_stamps), which separate the clock correction's error from the tick's.
WRAP32 = 1 << 32
WRAP40 = 1 << 40
METRES_PER_TICK = SPEED_OF_LIGHT / TS_FREQ

MEASUREMENT, DROP_NO_REFERENCE, DROP_CLOCK, DROP_EXPIRED, DROP_MALFORMED, DROP_UNKNOWN_TYPE = range(6)
# protocol enum tdoa_match: AUTO = what a Crazyflie's tag uses (TDoA2 youngest, TDoA3 random)
MATCH_AUTO, MATCH_RANDOM, MATCH_YOUNGEST = 0, 1, 2


def resolve_match(match: int, packet_type: int) -> int:
    if match != MATCH_AUTO:
        return match
    return MATCH_YOUNGEST if packet_type == TYPE_TDOA2 else MATCH_RANDOM


def now_ms(t_us: int) -> int:
    """Tag time in whole milliseconds (uint32), the clock of every expiry."""
    return (int(t_us) // 1000) & MASK32


class Slots:
    """n (id, value, end_ms) slots as the C's parallel arrays: unused = id 0, end 0. set() takes the first
    slot holding id, else the first that expires earliest; get() the first slot holding id if live."""

    def __init__(self, n: int, empty: tuple) -> None:
        self.id = [0] * n
        self.val: list[tuple] = [empty] * n
        self.end = [0] * n

    def set(self, rid: int, val: tuple, end: int) -> None:
        k = self.id.index(rid) if rid in self.id else min(range(len(self.id)), key=lambda i: (self.end[i], i))
        self.id[k], self.val[k], self.end[k] = rid, val, end

    def get(self, rid: int, now: int) -> tuple | None:
        if rid not in self.id:
            return None
        k = self.id.index(rid)
        return self.val[k] if self.end[k] > now else None


@dataclass
class AnchorCtx:
    id: int
    seq: int = 0
    rx_ts: float = 0
    tx_ts: float = 0
    last_ms: int = 0
    cc: float = 0.0
    bucket: int = 0
    packets: int = 0
    remote: Slots = field(default_factory=lambda: Slots(REMOTE_COUNT, (0, 0)))   # (seq, rx_ts)
    tof: Slots = field(default_factory=lambda: Slots(TOF_COUNT, (0,)))           # (tof,)

    def tof_of(self, rid: int, now: int) -> float:
        v = self.tof.get(rid, now)
        return v[0] if v is not None else 0

    def clock_update(self, rx_ts: float, tx_ts: float) -> bool:
        """The bucket rule; True if this sample is reliable."""
        if self.rx_ts == 0 or self.tx_ts == 0:
            return False
        drx = (rx_ts - self.rx_ts) % WRAP32
        dtx = (tx_ts - self.tx_ts) % WRAP32
        # a ratio outside [0.5, 2) (a zero TX interval too) is no clock ratio: never reliable, never stored
        # (the C's integer arithmetic, tdoa_clock.h, holds ratios in [0.5, 2] only; inside it, it equals this)
        cand = drx / dtx if dtx != 0 and dtx <= 2 * drx and drx < 2 * dtx else -1.0
        dev = cand - self.cc
        if -CC_ACCEPTED_NOISE < dev < CC_ACCEPTED_NOISE:
            self.cc = CC_FILTER * self.cc + (1.0 - CC_FILTER) * cand
            self.bucket = min(self.bucket + 1, CC_BUCKET_MAX)
            return True
        if self.bucket > 0:
            self.bucket -= 1
        elif 1.0 - CC_MAX_DEVIATION < cand < 1.0 + CC_MAX_DEVIATION:
            self.cc = cand
        return False


@dataclass(frozen=True)
class Measurement:
    anchor_a: int   # reference Ar
    anchor_b: int   # sender An
    diff: float     # d(tag, B) - d(tag, A) [m]
    ticks: float = 0.0   # the same in ticks (whole ticks unless whole_ticks=False)


class TdoaEngine:
    """whole_ticks=False keeps the fraction of the difference (analysis of unrounded stamps only)."""

    def __init__(self, whole_ticks: bool = True) -> None:
        self.slots: list[AnchorCtx | None] = [None] * STORAGE_COUNT
        self.offset = 0
        self.whole_ticks = whole_ticks

    def anchor(self, anchor_id: int) -> AnchorCtx | None:
        return next((a for a in self.slots if a is not None and a.id == anchor_id), None)

    def _get_or_create(self, anchor_id: int, now: int) -> tuple[AnchorCtx, bool]:
        a = self.anchor(anchor_id)
        if a is not None:
            return a, False
        victim, oldest = 0, now
        for i, s in enumerate(self.slots):
            if s is None:
                victim = i
                break
            if s.last_ms < oldest:
                victim, oldest = i, s.last_ms
        ctx = AnchorCtx(id=anchor_id)
        old = self.slots[victim]
        if old is None:
            self.slots[victim] = ctx
            return ctx, True
        # re-initialised in place, as the C's (and a Crazyflie's) pointer into the storage sees it: a sender
        # evicted by a reference lookup goes on writing into the slot now holding the new id
        old.__dict__.update(ctx.__dict__)
        return old, True

    def _match(self, an: AnchorCtx, now: int, youngest: bool) -> tuple[AnchorCtx | None, float, float]:
        """(reference, its rx_Ar_by_An, its ToF) as tdoa_engine.c find_reference: a copy of An's live records
        searched (a lookup may evict An itself when more than 16 anchors are in view), random from a rotating
        start, the first wins; youngest: the one heard last."""
        live = [(an.remote.id[k], *an.remote.val[k]) for k in range(REMOTE_COUNT) if an.remote.end[k] > now]
        start = 0
        if not youngest:
            self.offset = (self.offset + 1) & 0xFF
            start = self.offset
        best: tuple[AnchorCtx | None, float, float] = (None, 0, 0)
        for i in range(start, start + len(live)):
            rid, seq, rx = live[i % len(live)]
            tof = an.tof_of(rid, now)
            if youngest and not tof:
                continue
            ar, created = self._get_or_create(rid, now)
            if created or not tof or seq != ar.seq:
                continue
            if youngest and ar.last_ms <= (best[0].last_ms if best[0] is not None else 0):
                continue
            best = (ar, rx, tof)
            if not youngest:
                break
        return best

    def _ticks(self, an: AnchorCtx, ar: AnchorCtx, rx_ar: float, tof: float, rx_ts: float, tx_ts: float) -> float:
        drx = (rx_ts - ar.rx_ts) % WRAP32
        dtx = (tx_ts - rx_ar) % WRAP32
        ticks = float(drx) - (float(tof) + float(dtx)) * an.cc
        return float(int(ticks)) if self.whole_ticks else ticks

    def process(self, pkt: Packet, sender: int, rx_ts: float, t_us: int,
                match: int = MATCH_AUTO) -> tuple[int, Measurement | None]:
        """One parsed packet: (MEASUREMENT, measurement) or (DROP_*, None); the state is updated either way.
        Timestamps are integer ticks as on the wire, or float ticks (analysis of unrounded stamps)."""
        now = now_ms(t_us)
        an, _ = self._get_or_create(sender, now)
        rx_ts %= WRAP40
        an.packets = (an.packets + 1) & MASK32
        for r in pkt.remote:
            if r.rx_ts != 0:
                an.remote.set(r.id, (r.seq, r.rx_ts), now + REMOTE_VALID_MS)
            if r.tof != 0:
                an.tof.set(r.id, (r.tof,), now + TOF_VALID_MS)
        rc, meas = DROP_CLOCK, None
        if an.clock_update(rx_ts, pkt.tx_ts) and an.cc > 0.0:
            ar, rx_ar, tof = self._match(an, now, resolve_match(match, pkt.type) == MATCH_YOUNGEST)
            rc = DROP_NO_REFERENCE
            if ar is not None:
                ticks = self._ticks(an, ar, rx_ar, tof, rx_ts, pkt.tx_ts)
                meas, rc = Measurement(ar.id, sender, SPEED_OF_LIGHT * ticks / TS_FREQ, ticks), MEASUREMENT
        an.seq, an.rx_ts, an.tx_ts, an.last_ms = pkt.seq, rx_ts, pkt.tx_ts, now
        return rc, meas


def sender_of(src_addr: int) -> int:
    return int(src_addr) & 0xFF


def replay(t_us: list[int], rx_ts: list[int], src_addr: list[int], payloads: list[bytes],
           engine: TdoaEngine | None = None, match: int = MATCH_AUTO
           ) -> tuple[TdoaEngine, list[tuple[int, Measurement | None]]]:
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
        out.append(eng.process(pkt, sender, int(rx), int(t), match))
    return eng, out
