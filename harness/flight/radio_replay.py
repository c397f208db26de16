"""Recorded TDoA flights at radio level: synthesise the packets a tag would have received so that its
engine forms exactly the recorded differences.

Ideal clocks (no skew; every device counts the same ticks): a transmission at time t carries the TX
stamp round(t f) and the tag stamps its reception at the same instant plus a constant (a fixed virtual
distance), so every clock-correction sample is exactly 1. For a recorded measurement (A, B, d) at t:
A sends a packet at t - `lead` (it forms no measurement: NO_REFERENCE), then B sends at t reporting A's
packet as received at tx_A + ToF + d (in ticks) with ToF = `tof_ticks`; the engine's difference is then
round(d f / c) ticks: the recorded value within half a DW1000 tick (2.35 mm). A tag keeps an anchor's
remote data 30 ms, so each packet also lists every other anchor (up to 7) with a seq the tag has not heard
from it (stale entries from earlier packets could otherwise be references): A's packet and B's only
reference is the one intended.
Three packets per anchor (no remotes) warm the clock corrections up first. All packets carry the
anchor's LPP position. 32-bit and 40-bit wraps occur as on a real tag (every 67 ms and 17.2 s).
"""

from __future__ import annotations

import numpy as np

from harness.flight.data import KIND_TDOA, Flight, RadioStream
from harness.flight.radio_packets import ANCHOR_ADDR_BASE, PAYLOAD_MAX, RemoteInfo, tdoa2_payload, tdoa3_payload
from harness.twin.tdoa_engine import METRES_PER_TICK, TS_FREQ
from harness.errors import InputError

MASK32 = 0xFFFFFFFF
MASK40 = 0xFFFFFFFFFF
TOF_TICKS = 33000       # anchor-anchor ToF as reported (antenna delay included); any known value works
RX_OFFSET = 40000       # tag RX stamp - TX stamp (virtual distance + antenna delay)


class RadioReplayError(InputError):
    pass


def _payload(protocol: str, sender: int, seq: int, tx: int, remotes: list[RemoteInfo],
             pos: tuple[float, float, float]) -> bytes:
    if protocol == "tdoa2":
        return tdoa2_payload(sender, seq, tx, remotes, pos)
    return tdoa3_payload(seq, tx, remotes, pos)


def radio_from_recording(flight: Flight, protocol: str = "tdoa3", lead_us: int = 500) -> Flight:
    """The recorded TDoA flight with a radio stream whose engine output is its differences."""
    u = flight.uwb
    if u.kind != KIND_TDOA:
        raise RadioReplayError(f"{flight.name}: radio-level replay needs a TDoA recording")
    ids = sorted(int(i) for i in flight.anchors.ids)
    if protocol == "tdoa2" and (ids[0] < 0 or ids[-1] > 7):
        raise RadioReplayError(f"{flight.name}: TDoA2 carries anchor ids 0..7, the recording has {ids}")
    if ids[0] < 0 or ids[-1] > 255:
        raise RadioReplayError(f"{flight.name}: anchor ids must be 0..255")
    pos = {int(i): tuple(float(v) for v in p) for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    seq = {a: 0 for a in ids}
    rows: list[tuple[int, int, int, bytes]] = []

    def send(t_us: int, a: int, remotes: list[RemoteInfo]) -> int:
        tx = (int(round(t_us * 1e-6 * TS_FREQ)) & ~0x1FF) & MASK40
        named = {r.id for r in remotes} | {a}
        # the next seq of each other anchor: not yet sent, so no reference (rx_ts 1: a stored entry)
        remotes = remotes + [RemoteInfo(id=o, seq=seq[o], rx_ts=1) for o in ids if o not in named][:8 - len(remotes)]
        rows.append((t_us, (tx + RX_OFFSET) & MASK40, a, _payload(protocol, a, seq[a], tx & MASK32, remotes, pos[a])))
        seq[a] = (seq[a] + 1) & 0x7F
        return tx

    t0 = int(u.t_us[0]) if len(u) else 0
    # clock warm-up, 3 packets per anchor, within the millisecond before the first measurement
    step = min(1000, t0) // (3 * len(ids) + 1)
    if step < 1:
        raise RadioReplayError(f"{flight.name}: the first measurement is at t = {t0} us: no time before it "
                               "for the radio warm-up packets")
    for k in range(3 * len(ids)):
        send(t0 - (3 * len(ids) + 1 - k) * step, ids[k % len(ids)], [])
    for t, a, b, d in zip(u.t_us.tolist(), u.anchor_a.tolist(), u.anchor_b.tolist(), u.value.tolist()):
        a, b = int(a), int(b)
        t_ref = max(int(t) - lead_us, rows[-1][0])
        a_seq = seq[a]
        tx_a = send(t_ref, a, [])
        ticks = int(round(float(d) / METRES_PER_TICK))
        rx_a_by_b = (tx_a + TOF_TICKS + ticks) & MASK32
        send(int(t), b, [RemoteInfo(id=a, seq=a_seq, rx_ts=rx_a_by_b, tof=TOF_TICKS)])
    n = len(rows)
    payload = np.zeros((n, PAYLOAD_MAX), dtype=np.uint8)
    for k, r in enumerate(rows):
        payload[k, :len(r[3])] = np.frombuffer(r[3], dtype=np.uint8)
    radio = RadioStream(protocol=protocol, t_us=np.array([r[0] for r in rows], dtype=np.int64),
                        rx_ts=np.array([r[1] for r in rows], dtype=np.uint64),
                        src_addr=np.array([ANCHOR_ADDR_BASE | r[2] for r in rows], dtype=np.uint64),
                        length=np.array([len(r[3]) for r in rows], dtype=np.uint8), payload=payload,
                        true_skew_ppm={a: 0.0 for a in ids})
    meta = dict(flight.meta)
    meta["radio"] = {"protocol": protocol, "synthesised_from": "recorded differences", "packets": n}
    return Flight(name=f"{flight.name}-radio-{protocol}", anchors=flight.anchors, uwb=flight.uwb, truth=flight.truth,
                  imu=flight.imu, meta=meta, radio=radio, aux=flight.aux)
