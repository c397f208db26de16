"""Second half of the radio simulator (harness/flight/radio_sim.py): from TX/RX times to packets.

Walks the transmissions in time order keeping what every anchor last heard from every other (seq,
RX time in its own clock), builds each payload, keeps the ones the tag received, then runs the engine
twin over them to derive the measurement-level equivalent (same pairs, times and link errors).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from harness.flight.measurement_errors import DW1000_TICK_M, SPEED_OF_LIGHT, SimConfig, hardware_params
from harness.flight.data import KIND_TDOA, Flight, RadioStream, UwbStream
from harness.flight.radio_clock import TS_FREQ, DeviceClock
from harness.flight.radio_config import RadioConfig
from harness.flight.radio_packets import ANCHOR_ADDR_BASE, PAYLOAD_MAX, RemoteInfo, tdoa2_payload, tdoa3_payload
from harness.twin import lps_packets as lp
from harness.twin.tdoa_engine import MEASUREMENT, TdoaEngine

MASK32 = 0xFFFFFFFF
MASK40 = 0xFFFFFFFFFF
# A reference heard by the tag this many ticks (or more) before the sender's packet may have wrapped the
# sender's 32-bit gap tx_An - rxAr_by_An (docs/radio.md): 2^32 less 16 us for the flight times.
WRAP_GAP_TICKS = (1 << 32) - (1 << 20)
TDOA2_FRAME_S = (1 << 30) / TS_FREQ   # 8 slots of 2^27 ticks


def _in(t: float, window: tuple[float, float] | None, extra: float = 0.0) -> bool:
    return window is not None and window[0] <= t < window[1] + extra


def _anchor_rx(cfg: RadioConfig, ids: np.ndarray, clocks: dict[int, DeviceClock], who: np.ndarray,
               t_tx: np.ndarray, apos: dict[int, np.ndarray], anchor_err: np.ndarray,
               rng: np.random.Generator) -> dict[int, np.ndarray]:
    """RX stamp (ticks, unwrapped, not yet rounded to whole ticks) of every transmission at every anchor;
    anchor_err [m] (anchor index, transmission): the error model's share, late stamps."""
    out = {}
    delay_s = cfg.antenna_delay_ticks / TS_FREQ
    for k, b in enumerate(ids):
        d = np.array([np.linalg.norm(apos[int(a)] - apos[int(b)]) for a in who])
        t = t_tx + delay_s + d / SPEED_OF_LIGHT
        noise = rng.normal(0.0, cfg.rx_noise_m / DW1000_TICK_M, size=len(who))
        out[int(b)] = clocks[int(b)].local(t) + noise + anchor_err[k] / DW1000_TICK_M
    return out


def _tof(cfg: RadioConfig, sim: SimConfig | None, hw: Any, clocks: dict[int, DeviceClock],
         apos: dict[int, np.ndarray], a: int, b: int, t: float, rng: np.random.Generator) -> tuple[int, float]:
    """ToF b -> a as anchor a's ranging estimates it: a's ticks, antenna delay included (uint16), and unrounded."""
    tof_s = float(np.linalg.norm(apos[a] - apos[b])) / SPEED_OF_LIGHT + cfg.antenna_delay_ticks / TS_FREQ
    ticks = tof_s * TS_FREQ * (1.0 + float(clocks[a].skew_at(t))) + rng.normal(0.0, cfg.tof_noise_m / DW1000_TICK_M)
    if sim is not None:
        ticks -= hw.pair_offset(b, a, sim.antenna) / DW1000_TICK_M   # the pair offset o_BA of the model
    exact = float(np.clip(ticks, 1, 0xFFFF))
    return int(np.round(exact)), exact


def assemble(flight: Flight, cfg: RadioConfig, sim: SimConfig | None, clocks: dict[int, DeviceClock],
             tag: DeviceClock, who: np.ndarray, t_tx: np.ndarray, tx_ticks: np.ndarray, t_rx: np.ndarray,
             rx_ticks: np.ndarray, heard_by_tag: np.ndarray, collided: np.ndarray, excess: np.ndarray,
             anchor_err: np.ndarray, silent: dict[int, tuple[float, float]], rng_loss: np.random.Generator,
             rng_noise: np.random.Generator) -> Flight:
    ids = np.array(sorted(clocks))
    apos = {int(i): np.asarray(p, dtype=np.float64) for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    hw = hardware_params(sim.antenna, flight.anchors.ids) if sim is not None else None
    arx = _anchor_rx(cfg, ids, clocks, who, t_tx, apos, anchor_err, rng_noise)
    anchor_miss = rng_loss.random((len(who), len(ids))) < cfg.anchor_loss
    heard: dict[int, dict[int, tuple[int, float, float, int]]] = {int(a): {} for a in ids}   # (seq, rx, t, event)
    latest_tx: dict[int, int] = {}                       # anchor -> event of its latest transmission
    seq = {int(a): 0 for a in ids}
    restarted = {int(a): False for a in ids}
    rows: list[tuple[int, int, int, bytes, int]] = []   # (t_us, rx_ts, sender, payload, event)
    exact: dict[int, lp.Packet] = {}                     # event -> the packet with unrounded stamps
    for e in range(len(who)):
        a, t = int(who[e]), float(t_tx[e])
        if a in silent and t >= silent[a][1] and not restarted[a]:
            restarted[a], seq[a], heard[a] = True, 0, {}
        remotes: list[RemoteInfo] = []
        remotes_x: list[lp.Remote] = []
        for b in ids:
            b = int(b)
            h = heard[a].get(b)
            if b == a or h is None or (cfg.protocol == "tdoa3" and t - h[2] > cfg.tdoa3_validity_s):
                continue
            # TDoA2: a slot holds the latest packet of that anchor, heard in the last frame; missed: zero
            if cfg.protocol == "tdoa2" and (h[3] != latest_tx.get(b) or t - h[2] > TDOA2_FRAME_S):
                continue
            tof_unknown = _in(t, silent.get(a), cfg.reboot_tof_s) or _in(t, silent.get(b), cfg.reboot_tof_s)
            tof, tof_x = (0, 0.0) if tof_unknown else _tof(cfg, sim, hw, clocks, apos, a, b, t, rng_noise)
            remotes.append(RemoteInfo(id=b, seq=h[0], rx_ts=int(round(h[1])) & MASK32, tof=tof))
            remotes_x.append(lp.Remote(id=b, seq=h[0], tof=tof_x if tof != 0 else 0, rx_ts=h[1] % 2.0**32))
        pos = tuple(float(v) for v in apos[a]) if cfg.lpp else None
        tx32 = int(tx_ticks[e]) & MASK32
        if cfg.protocol == "tdoa2":
            payload = tdoa2_payload(a, seq[a], tx32, remotes, pos)  # type: ignore[arg-type]
        else:
            # a full entry (with the distance) whenever the anchor has one, as real anchors send
            remotes, remotes_x = remotes[:8], remotes_x[:8]
            payload = tdoa3_payload(seq[a], tx32, remotes, pos, [r.tof != 0 for r in remotes])  # type: ignore[arg-type]
        for k, b in enumerate(ids):
            b = int(b)
            if b != a and not anchor_miss[e, k] and not collided[e] and not _in(t, silent.get(b)):
                heard[b][a] = (seq[a], float(arx[b][e]), t, e)
        if heard_by_tag[e]:
            rows.append((int(round(t_rx[e] * 1e6)), int(round(rx_ticks[e])) & MASK40, a, payload, e))
            if cfg.exact_stamps:
                exact[e] = lp.Packet(type=payload[0], seq=seq[a], tx_ts=tx32, remote=remotes_x)
        seq[a] = (seq[a] + 1) & 0x7F
        latest_tx[a] = e
    rows.sort(key=lambda r: (r[0], r[4]))
    out = _flight(flight, cfg, clocks, tag, rows, excess, anchor_err, sim, hw)
    if cfg.exact_stamps and out.radio is not None:
        out = replace(out, radio=replace(out.radio, exact=[exact[r[4]] for r in rows],
                                         exact_rx=np.array([float(rx_ticks[r[4]]) % 2.0**40 for r in rows])))
    return out


def _radio_stream(cfg: RadioConfig, rows: list[tuple[int, int, int, bytes, int]], truth: dict[int, float],
                  clocks: dict[int, DeviceClock], tag: DeviceClock) -> RadioStream:
    n = len(rows)
    t = np.array([r[0] for r in rows], dtype=np.float64) * 1e-6
    sender = np.array([r[2] for r in rows], dtype=np.int64)
    skew = np.zeros(n)
    for a, clk in clocks.items():
        sel = sender == a
        skew[sel] = ((1.0 + tag.skew_at(t[sel])) / (1.0 + clk.skew_at(t[sel])) - 1.0) * 1e6
    payload = np.zeros((n, PAYLOAD_MAX), dtype=np.uint8)
    for k, r in enumerate(rows):
        payload[k, :len(r[3])] = np.frombuffer(r[3], dtype=np.uint8)
    return RadioStream(protocol=cfg.protocol, t_us=np.array([r[0] for r in rows], dtype=np.int64),
                       rx_ts=np.array([r[1] for r in rows], dtype=np.uint64),
                       src_addr=np.array([ANCHOR_ADDR_BASE | r[2] for r in rows], dtype=np.uint64),
                       length=np.array([len(r[3]) for r in rows], dtype=np.uint8), payload=payload,
                       true_skew_ppm=truth, true_skew_pkt=skew)


def _flight(flight: Flight, cfg: RadioConfig, clocks: dict[int, DeviceClock], tag: DeviceClock,
            rows: list[tuple[int, int, int, bytes, int]], excess: np.ndarray, anchor_err: np.ndarray,
            sim: SimConfig | None, hw: Any) -> Flight:
    """Run the engine twin over the packets: the measurement-level equivalent and the clock truth. A
    difference carries the tag's reception errors of both packets, the pair offset and the sender's RX
    stamp error of the reference's packet (a late stamp shortens tx_An - rxAr_by_An: + on the difference)."""
    row_of = {int(a): k for k, a in enumerate(sorted(clocks))}
    engine = TdoaEngine()
    last_event: dict[int, int] = {}
    last_rx: dict[int, int] = {}
    last_t: dict[int, float] = {}
    t_us, a_ids, b_ids, err, formed, wrapped = [], [], [], [], [], []
    for t, rx, sender, payload, e in rows:
        rc, pkt = lp.parse(payload, sender)
        if rc == lp.OK:
            rc, meas = engine.process(pkt, sender, rx, t)
            if rc == MEASUREMENT and meas is not None:
                ref = last_event[meas.anchor_a]
                pair = hw.pair_offset(meas.anchor_a, sender, sim.antenna) if sim is not None else 0.0
                t_us.append(t)
                a_ids.append(meas.anchor_a)
                b_ids.append(sender)
                err.append(float(excess[e] - excess[ref] + anchor_err[row_of[sender], ref]) + pair)
                formed.append(meas.diff)
                wrapped.append((rx - last_rx[meas.anchor_a]) % (1 << 40) >= WRAP_GAP_TICKS)
        last_event[sender] = e
        last_rx[sender] = rx
        last_t[sender] = t * 1e-6
    tt = np.array(t_us, dtype=np.int64)
    a_arr, b_arr = np.array(a_ids, dtype=np.int64), np.array(b_ids, dtype=np.int64)
    pos = flight.truth.position_at(tt)
    ap = {int(i): p for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    pa = np.array([ap[int(i)] for i in a_arr]).reshape(-1, 3)
    pb = np.array([ap[int(i)] for i in b_arr]).reshape(-1, 3)
    true_value = np.linalg.norm(pos - pb, axis=1) - np.linalg.norm(pos - pa, axis=1)
    truth = {a: float(((1.0 + tag.skew_at(t)) / (1.0 + clocks[a].skew_at(t)) - 1.0) * 1e6)
             for a, t in last_t.items()}
    value = true_value + np.array(err)
    # A reference whose packet the sender heard > 2^32 ticks before transmitting wraps the engine's 32-bit
    # arithmetic (2^32 (cc - 1) ticks: mm to hundreds of m; a Crazyflie's engine forms it too): both levels
    # carry the value the engine formed, so both see the same wrong measurement.
    wrap = np.array(wrapped, dtype=bool)
    value[wrap] = np.array(formed)[wrap]
    uwb = UwbStream(kind=KIND_TDOA, t_us=tt, anchor_a=a_arr, anchor_b=b_arr, value=value, true_value=true_value)
    meta = dict(flight.meta)
    meta["radio"] = {"protocol": cfg.protocol, "seed": cfg.seed, "packets": len(rows), "loss": cfg.loss,
                     "max_ppm": cfg.max_ppm, "reboots": [list(r) for r in cfg.reboots]}
    return Flight(name=f"{flight.name}-radio-{cfg.protocol}", anchors=flight.anchors, uwb=uwb, truth=flight.truth,
                  imu=flight.imu, meta=meta, radio=_radio_stream(cfg, rows, truth, clocks, tag))
