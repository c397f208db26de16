"""What the two levels of one flight feed the estimator (harness/radio_compare.py).

A simulated radio-level flight carries its packets (`radio`) and the same measurements as differences
(`uwb`: the pairs and times the engine twin forms, true difference + the same link errors). This module
checks that precondition and measures how the levels still differ:

* the engine twin over the packets: packets, measurements, drops by reason, same (time, pair) as `uwb`;
* the values: radio level (the twin on the wire's integer stamps) minus measurement level, and each
  level's error against the true difference;
* the firmware: each RESULT's measurement value, reconstructed as innovation + bias + h(x before the
  update) under the twin's pair, against the twin's value. A firmware whose engine forms other pairs
  (e.g. a binary built before an engine change) differs by centimetres to metres; the same engine by
  float rounding (~1e-6 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.config import STAGE_ROBUST_UPDATE
from harness.errors import InputError
from harness.flight.data import Flight
from harness.stream.results_file import OUTCOME_RESULT
from harness.stream.streamer import RunResult
from harness.twin.tdoa_engine import MEASUREMENT, Measurement, replay
from protocol._generated import DropReason, ResultFlag, Status

FIRMWARE_TOLERANCE_M = 1e-3   # a RESULT's value this far from the twin's is another measurement


@dataclass(frozen=True)
class TwinStream:
    outcome: np.ndarray     # (P,) per packet: MEASUREMENT (0) or the drop reason
    anchor_a: np.ndarray    # (M,) reference anchor of each measurement
    anchor_b: np.ndarray    # (M,) sender
    value: np.ndarray       # (M,) d(tag, B) - d(tag, A) [m]
    t_us: np.ndarray        # (M,)


@dataclass(frozen=True)
class StreamComparison:
    packets: int
    measurements: int
    drops: dict[str, int]            # drop reason name -> packets (only reasons that occurred)
    same_pairs: bool                 # the twin's (time, A, B) sequence is the measurement level's
    diff_mean_m: float               # radio value - measurement-level value, same measurement
    diff_rms_m: float
    diff_max_m: float
    err_rms_meas_m: float            # value - true difference, measurement level
    err_rms_radio_m: float           # the same at radio level


@dataclass(frozen=True)
class FirmwareCheck:
    checked: int                     # RESULTs compared
    mismatched: int                  # outcome differs from the twin's, or value beyond FIRMWARE_TOLERANCE_M
    max_abs_m: float                 # largest |firmware value - twin value|

    @property
    def ok(self) -> bool:
        return self.mismatched == 0


def twin_stream(flight: Flight) -> TwinStream:
    """The engine twin over the flight's packets, as the firmware processes them."""
    r = flight.radio
    if r is None:
        raise InputError(f"flight {flight.name} has no radio stream")
    payloads = [bytes(r.payload[k, :int(r.length[k])]) for k in range(len(r))]
    _, out = replay([int(v) for v in r.t_us], [int(v) for v in r.rx_ts], [int(v) for v in r.src_addr], payloads)
    meas: list[Measurement] = [mm for _, mm in out if mm is not None]
    t = np.array([int(r.t_us[k]) for k, (_, mm) in enumerate(out) if mm is not None], dtype=np.int64)
    return TwinStream(outcome=np.array([rc for rc, _ in out], dtype=np.int64),
                      anchor_a=np.array([mm.anchor_a for mm in meas], dtype=np.int64),
                      anchor_b=np.array([mm.anchor_b for mm in meas], dtype=np.int64),
                      value=np.array([mm.diff for mm in meas], dtype=np.float64), t_us=t)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


def compare_streams(flight: Flight, twin: TwinStream | None = None) -> StreamComparison:
    """Both levels' measurement streams of a simulated radio-level flight (needs `uwb.true_value`)."""
    tw = twin if twin is not None else twin_stream(flight)
    u = flight.uwb
    drops = {DropReason(int(k)).name.lower(): int(np.count_nonzero(tw.outcome == k))
             for k in np.unique(tw.outcome) if k != MEASUREMENT}
    same = (len(tw.value) == len(u) and bool(np.array_equal(tw.t_us, u.t_us))
            and bool(np.array_equal(tw.anchor_a, u.anchor_a)) and bool(np.array_equal(tw.anchor_b, u.anchor_b)))
    nan = float("nan")
    diff = tw.value - u.value if same else np.array([nan])
    truth = u.true_value if u.true_value is not None else np.full(len(u), nan)
    return StreamComparison(
        packets=len(tw.outcome), measurements=len(tw.value), drops=drops, same_pairs=same,
        diff_mean_m=float(np.mean(diff)), diff_rms_m=_rms(diff), diff_max_m=float(np.max(np.abs(diff))),
        err_rms_meas_m=_rms(u.value - truth), err_rms_radio_m=_rms(tw.value - truth) if same else nan)


def firmware_values(run: RunResult, flight: Flight, anchor_a: np.ndarray, anchor_b: np.ndarray) -> np.ndarray:
    """The measurement value behind each RESULT of a radio-level run: innovation + bias + h(x before the
    update) under the given pairs (one per RESULT, in order). x before = x after - K innovation: the scalar
    update; the robust update iterates its weights, so it is refused. NaN where the supervisor restarted the filter."""
    if run.config.stages & STAGE_ROBUST_UPDATE:
        raise ValueError("the robust update iterates: its state before the update is not in the RESULT")
    res = run.results[run.results["outcome"] == OUTCOME_RESULT]
    if len(res) != len(anchor_a):
        raise ValueError(f"{len(res)} RESULTs for {len(anchor_a)} pairs")
    innov = res["innovation"].astype(np.float64)
    gain = np.stack([res["gain_x"], res["gain_y"], res["gain_z"]], axis=1).astype(np.float64)
    after = np.stack([res["px"], res["py"], res["pz"]], axis=1).astype(np.float64)
    before = after - gain * innov[:, None]
    pos = {int(i): np.asarray(p, dtype=np.float64) for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    pa = np.array([pos[int(i)] for i in anchor_a]).reshape(-1, 3)
    pb = np.array([pos[int(i)] for i in anchor_b]).reshape(-1, 3)
    h = np.linalg.norm(before - pb, axis=1) - np.linalg.norm(before - pa, axis=1)
    z = innov + res["bias"].astype(np.float64) + h
    z[(res["flags"] & int(ResultFlag.DIVERGED | ResultFlag.GAP_RESTART)) != 0] = np.nan   # estimate after a restart
    z[res["status"] == int(Status.REJECTED_BASELINE)] = np.nan     # answered before the model: no value in it
    return z


def firmware_check(run: RunResult, flight: Flight, twin: TwinStream | None = None) -> FirmwareCheck:
    """Did the firmware's engine form the twin's measurements (same packets, pairs and values)?"""
    tw = twin if twin is not None else twin_stream(flight)
    out = run.results["outcome"]
    formed = out == OUTCOME_RESULT
    if len(out) != len(tw.outcome) or not np.array_equal(formed, tw.outcome == MEASUREMENT):
        n = min(len(out), len(tw.outcome))
        bad = int(np.count_nonzero(formed[:n] != (tw.outcome[:n] == MEASUREMENT))) + abs(len(out) - len(tw.outcome))
        return FirmwareCheck(checked=int(np.count_nonzero(formed)), mismatched=bad, max_abs_m=float("inf"))
    err = np.abs(firmware_values(run, flight, tw.anchor_a, tw.anchor_b) - tw.value)
    # the firmware refused REJECTED_BASELINE ones: the twin's value must be beyond the anchors' distance
    base = run.results[formed]["status"] == int(Status.REJECTED_BASELINE)
    pos = {int(i): np.asarray(p, dtype=np.float64) for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    dist = np.array([np.linalg.norm(pos[int(a)] - pos[int(b)]) for a, b in zip(tw.anchor_a[base], tw.anchor_b[base])])
    wrong_base = int(np.count_nonzero(np.abs(tw.value[base]) < dist - FIRMWARE_TOLERANCE_M))
    err = err[np.isfinite(err)]
    return FirmwareCheck(checked=len(err) + int(np.count_nonzero(base)),
                         mismatched=int(np.count_nonzero(err > FIRMWARE_TOLERANCE_M)) + wrong_base,
                         max_abs_m=float(err.max()) if len(err) else 0.0)


@dataclass(frozen=True)
class SharedReception:
    """How much of a recorded flight's white TDoA noise sits on the tag's receptions. Two measurements in
    a row where the first's sender is the second's reference (TDoA2: (n-1, n) then (n, n+1)) share the
    tag's reception of that packet: its noise enters one with + and the other with -, so their errors
    correlate at -s_tag^2 / s^2 (-0.5 if all the noise were on the tag's receptions, 0 if none)."""

    n_shared: int
    corr_shared: float
    n_other: int                     # consecutive measurements that share no reception (control: ~0)
    corr_other: float

    @property
    def tag_share(self) -> float:
        """Share of the white variance of a difference on the tag's two receptions (-2 corr)."""
        return -2.0 * self.corr_shared


def shared_reception(flight: Flight, window: int = 15, max_gap_us: int = 5000, clip_m: float = 0.3) -> SharedReception:
    """Residuals (value - true difference, minus each pair's centred moving average over `window` of its
    measurements: the pose-dependent bias goes) of consecutive measurements < max_gap_us apart."""
    u = flight.uwb
    pos = flight.truth.position_at(u.t_us)
    ap = {int(i): np.asarray(p, dtype=np.float64) for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    pa = np.array([ap[int(i)] for i in u.anchor_a]).reshape(-1, 3)
    pb = np.array([ap[int(i)] for i in u.anchor_b]).reshape(-1, 3)
    err = u.value - (np.linalg.norm(pos - pb, axis=1) - np.linalg.norm(pos - pa, axis=1))
    res = np.full(len(u), np.nan)
    for a, b in set(zip(u.anchor_a.tolist(), u.anchor_b.tolist())):
        k = np.flatnonzero((u.anchor_a == a) & (u.anchor_b == b))
        if len(k) >= window:
            padded = np.pad(err[k], window // 2, mode="edge")
            res[k] = err[k] - np.convolve(padded, np.ones(window) / window, mode="valid")[:len(k)]
    near = (np.diff(u.t_us) < max_gap_us) & (np.abs(res[:-1]) < clip_m) & (np.abs(res[1:]) < clip_m)
    shared = near & (u.anchor_b[:-1] == u.anchor_a[1:])
    other = near & ~shared & (u.anchor_b[:-1] != u.anchor_b[1:]) & (u.anchor_a[:-1] != u.anchor_a[1:])

    def corr(sel: np.ndarray) -> float:
        return float(np.corrcoef(res[:-1][sel], res[1:][sel])[0, 1]) if sel.sum() > 50 else float("nan")
    return SharedReception(int(shared.sum()), corr(shared), int(other.sum()), corr(other))
