"""LPS radio simulator: the anchor packets a tag receives while it flies a simulated trajectory.

Anchors and tag have their own DW1000 clocks (harness/flight/radio_clock.py: offset, skew within
+-10 ppm, slow random walk, reboots). TDoA2: anchors transmit in their slot of the master's 8-slot frame
(2^27 ticks per slot); TDoA3: each anchor at 400 Hz / (anchors + 1), clamped to [20, 50] Hz, with
+-5 ms random delay. TX times are scheduled with the low 9 bits zeroed (DW1000 delayed TX). Each
packet reports, per other anchor, the seq and RX time (own clock) of the last packet heard from it and
the anchor-anchor time of flight in own ticks including the antenna delay (what the anchors' ranging
measures). Every device stamps RX late and TX early by half the antenna delay.

The error model of harness/flight/measurement_errors.py enters at timestamp level: each tag reception is
delayed by the link's pose-dependent bias + NLOS excess + noise (std tdoa_std / sqrt(2) per link, so a
difference has tdoa_std); the pair offset o_AB enters through the ToF anchor B reports for A.

The returned Flight carries both levels: `radio` (the packets) and `uwb` (the measurement-level
equivalent: for each packet the engine turns into a measurement, the true difference plus the same
link errors), so a flight can be flown either way and the two compared.
"""

from __future__ import annotations

import numpy as np

from harness.flight.arena import NLOS_BOXES, Arena
from harness.flight.measurement_errors import (DW1000_TICK_M, SPEED_OF_LIGHT, SimConfig, _link_nlos, hardware_params,
                                         link_directions, range_bias)
from harness.flight.data import Flight
from harness.flight.radio_clock import TS_FREQ, DeviceClock
from harness.flight.radio_assemble import assemble
from harness.flight.radio_config import PROTOCOLS, RadioConfig, RadioSimError  # noqa: F401 (re-exported)

SLOT_TICKS = 2**27
TX_GUARD_S = 1e-6 + 128 * 1017.63e-9      # guard + preamble before the scheduled TX


def _tx_schedule(cfg: RadioConfig, ids: np.ndarray, clocks: dict[int, DeviceClock], t0: float, t1: float,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Nominal TX times [s] and sender ids, time ordered."""
    ts, who = [], []
    if cfg.protocol == "tdoa2":
        master = clocks[int(ids.min())]
        frame_s = 8 * SLOT_TICKS / TS_FREQ / (1.0 + float(master.skew_at(t0)))
        k = np.arange(int((t1 - t0) / frame_s))
        for aid in ids:
            ts.append(t0 + k * frame_s + int(aid) * frame_s / 8 + TX_GUARD_S)
            who.append(np.full(len(k), int(aid)))
    else:
        period = 1.0 / float(np.clip(cfg.tdoa3_system_hz / (len(ids) + 1), 20.0, 50.0))
        n = int((t1 - t0) / period) + 2
        for aid in ids:
            steps = period + rng.uniform(-cfg.tdoa3_delay_s, cfg.tdoa3_delay_s, size=n)
            t = t0 + rng.uniform(0, period) + np.concatenate([[0.0], np.cumsum(steps[:-1])])
            ts.append(t[t < t1])
            who.append(np.full(int(np.count_nonzero(t < t1)), int(aid)))
    t_all, w_all = np.concatenate(ts), np.concatenate(who)
    order = np.argsort(t_all, kind="stable")
    return t_all[order], w_all[order]


def _link_errors(sim: SimConfig | None, cfg: RadioConfig, arena: Arena, flight: Flight, who: np.ndarray,
                 t_rx: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Excess path [m] of each tag reception (0 without an error model)."""
    if sim is None or len(who) == 0:
        return np.zeros(len(who))
    anchors = arena.anchors
    if anchors.orientations is None:
        raise RadioSimError("the error model needs anchor orientations")
    idx = {int(i): k for k, i in enumerate(anchors.ids)}
    k = np.array([idx[int(a)] for a in who])
    pos, quat = flight.truth.position_at(t_rx * 1e6), flight.truth.quat_at(t_rx * 1e6)
    hw = hardware_params(sim.antenna, anchors.ids)
    bias = range_bias(sim.antenna, hw, who, anchors.positions[k], anchors.orientations[k], pos, quat)
    _, ut, _ = link_directions(anchors.positions[k], anchors.orientations[k], pos, quat)
    nlos, _ = _link_nlos(sim.nlos, arena, anchors.positions[k], pos, rng)
    noise = rng.normal(0.0, sim.tdoa_std * np.sqrt(cfg.tag_noise_share / 2.0), size=len(who))
    return bias + sim.antenna.pair_att_k * ut[:, 2] + nlos + noise


def simulate_radio(flight: Flight, cfg: RadioConfig, sim: SimConfig | None) -> Flight:
    """The radio-level version of a simulated flight (its truth, IMU and anchors). sim: the error model
    applied at timestamp level (None: geometry and clocks only)."""
    cfg.validate()
    ids = np.sort(flight.anchors.ids.astype(np.int64))
    if cfg.protocol == "tdoa2" and (ids.min() < 0 or ids.max() > 7):
        raise RadioSimError(f"TDoA2 needs anchor ids 0..7, got {ids.tolist()}")
    if len(ids) < 2 or ids.min() < 0 or ids.max() > 255:
        raise RadioSimError("need at least two anchors with ids 0..255")
    rng_clk, rng_sched, rng_loss, rng_err, rng_noise, rng_anchor = (
        np.random.default_rng(s) for s in np.random.SeedSequence([cfg.seed, 15]).spawn(6))
    t0 = float(flight.truth.t_us[0]) * 1e-6 + 0.01
    t1 = float(flight.truth.t_us[-1]) * 1e-6
    clocks = {int(a): DeviceClock(rng_clk, t1 + 1.0, cfg.max_ppm, cfg.walk_ppm) for a in ids}
    tag = DeviceClock(rng_clk, t1 + 1.0, cfg.max_ppm, cfg.walk_ppm)
    silent: dict[int, tuple[float, float]] = {}
    for aid, tr in cfg.reboots:
        if int(aid) not in clocks:
            raise RadioSimError(f"reboot of unknown anchor {aid}")
        clocks[int(aid)].reboot(t0 + tr + cfg.reboot_gap_s)
        silent[int(aid)] = (t0 + tr, t0 + tr + cfg.reboot_gap_s)
    t_nom, who = _tx_schedule(cfg, ids, clocks, t0, t1, rng_sched)
    keep = np.array([not (int(a) in silent and silent[int(a)][0] <= t < silent[int(a)][1])
                     for a, t in zip(who, t_nom)], dtype=bool)
    t_nom, who = t_nom[keep], who[keep]
    # TX stamps: the anchor's clock at the nominal time, low 9 bits cleared; the true TX time follows.
    tx_ticks = np.zeros(len(who))
    t_tx = np.zeros(len(who))
    for a in ids:
        sel = who == a
        raw = clocks[int(a)].local(t_nom[sel])
        stamp = np.floor(raw / 512.0) * 512.0
        tx_ticks[sel] = stamp
        t_tx[sel] = clocks[int(a)].true_time(stamp, t_nom[sel])
    t_tx = t_tx + rng_noise.normal(0.0, cfg.tx_noise_m / SPEED_OF_LIGHT, size=len(who))
    half_delay_s = 0.5 * cfg.antenna_delay_ticks / TS_FREQ
    apos = {int(i): p for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    arena = Arena(anchors=flight.anchors, boxes=NLOS_BOXES if (sim is not None and sim.obstacles) else ())
    # Tag receptions
    tag_pos = flight.truth.position_at(t_tx * 1e6)
    rng_dist = np.linalg.norm(tag_pos - np.stack([apos[int(a)] for a in who]), axis=1)
    excess = _link_errors(sim, cfg, arena, flight, who, t_tx, rng_err)
    # the error model's noise on the anchors' RX stamps [m], (anchor, transmission)
    anchor_std = 0.0 if sim is None else sim.tdoa_std * np.sqrt(1.0 - cfg.tag_noise_share)
    anchor_err = rng_anchor.normal(0.0, anchor_std, size=(len(ids), len(who)))
    t_rx = t_tx + 2 * half_delay_s + (rng_dist + excess) / SPEED_OF_LIGHT
    rx_ticks = tag.local(t_rx) + rng_noise.normal(0.0, cfg.rx_noise_m / DW1000_TICK_M, size=len(who))
    gap = np.diff(t_tx)
    collided = np.concatenate([[False], gap < cfg.airtime_s]) | np.concatenate([gap < cfg.airtime_s, [False]])
    heard_by_tag = (rng_loss.random(len(who)) >= cfg.loss) & ~collided
    return assemble(flight, cfg, sim, clocks, tag, who, t_tx, tx_ticks, t_rx, rx_ticks, heard_by_tag, collided,
                    excess, anchor_err, silent, rng_loss, rng_noise)
