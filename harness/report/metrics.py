"""Accuracy (position RMSE against ground truth) and latency (device cost, round trip) of a run."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from harness.flight.data import Flight
from harness.stream.results_file import OUTCOME_ERROR, OUTCOME_LOST, OUTCOME_RESULT
from harness.stream.streamer import RunResult
from harness.kinds import KINDS
from protocol.messages import CostUnit, ErrorCode, ResultFlag, Stage, Status

DEFAULT_BUDGET_S = 5e-3  # one UWB slot at 200 Hz, the paper's rate


@dataclass(frozen=True)
class LatencySummary:
    """Percentiles in microseconds (or instructions, for an instruction-counting device)."""

    n: int
    p50: float
    p90: float
    p99: float
    p999: float
    max: float
    mean: float
    jitter_p99: float        # p99 of |x - median|
    deadline_misses: int     # samples above the budget
    budget: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def latency_summary(values: np.ndarray, budget: float) -> LatencySummary:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        nan = float("nan")
        return LatencySummary(0, nan, nan, nan, nan, nan, nan, nan, 0, budget)
    p50, p90, p99, p999 = np.percentile(v, [50, 90, 99, 99.9])
    return LatencySummary(n=int(v.size), p50=float(p50), p90=float(p90), p99=float(p99), p999=float(p999),
                          max=float(v.max()), mean=float(v.mean()),
                          jitter_p99=float(np.percentile(np.abs(v - p50), 99)),
                          deadline_misses=int(np.count_nonzero(v > budget)), budget=budget)


@dataclass(frozen=True)
class AccuracySummary:
    n: int
    rmse: float        # 3-D position RMSE [m]
    rmse_xy: float
    rmse_z: float
    max_error: float
    accepted: int
    rejected_kinematic: int
    rejected_chi2: int
    rejected_geometry: int
    z_mean_error: float = float("nan")   # mean of estimate - truth along z [m] (a height bias shows here)
    rejected_baseline: int = 0   # TDoA |difference| >= the anchors' distance (as a Crazyflie's filter)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def position_errors(run: RunResult, flight: Flight) -> tuple[np.ndarray, np.ndarray]:
    """(t_us, error vectors) for every measurement that produced a RESULT."""
    res = run.results
    ok = res["outcome"] == OUTCOME_RESULT
    t_us = res["t_us"][ok].astype(np.int64)
    # column by column (same values as estimate - truth.position_at): copies of the selected rows or of
    # whole (N, 3) temporaries would multiply the memory of a 1-hour run's summary
    t, tt = t_us.astype(np.float64), flight.truth.t_us.astype(np.float64)
    err = np.empty((len(t_us), 3))
    for k, name in enumerate(("px", "py", "pz")):
        err[:, k] = res[name][ok]
        err[:, k] -= np.interp(t, tt, flight.truth.pos[:, k])
    return t_us, err


def _rows(fn: Callable[[np.ndarray], np.ndarray], err: np.ndarray, block: int = 1 << 16) -> np.ndarray:
    """fn applied to blocks of rows (same values as on the whole array, without (N, 3) temporaries)."""
    out = np.empty(len(err))
    for i in range(0, len(err), block):
        out[i:i + block] = fn(err[i:i + block])
    return out


def accuracy_of(err: np.ndarray, status: np.ndarray) -> AccuracySummary:
    """The accuracy of these answered measurements: error vectors (estimate - truth) and RESULT statuses."""
    if len(err) == 0:
        nan = float("nan")
        return AccuracySummary(0, nan, nan, nan, nan, 0, 0, 0, 0, nan)
    norm = _rows(lambda e: np.linalg.norm(e, axis=1), err)
    return AccuracySummary(
        n=len(err),
        rmse=float(np.sqrt(np.mean(norm ** 2))),
        rmse_xy=float(np.sqrt(np.mean(_rows(lambda e: np.sum(e[:, :2] ** 2, axis=1), err)))),
        rmse_z=float(np.sqrt(np.mean(err[:, 2] ** 2))),
        max_error=float(norm.max()),
        accepted=int(np.count_nonzero(status == Status.ACCEPTED)),
        rejected_kinematic=int(np.count_nonzero(status == Status.REJECTED_KINEMATIC)),
        rejected_chi2=int(np.count_nonzero(status == Status.REJECTED_CHI2)),
        rejected_geometry=int(np.count_nonzero(status == Status.REJECTED_GEOMETRY)),
        z_mean_error=float(np.mean(err[:, 2])),
        rejected_baseline=int(np.count_nonzero(status == Status.REJECTED_BASELINE)),
    )


def accuracy_summary(run: RunResult, flight: Flight) -> AccuracySummary:
    _, err = position_errors(run, flight)
    return accuracy_of(err, run.results["status"][run.results["outcome"] == OUTCOME_RESULT])


def health_summary(run: RunResult) -> dict[str, object]:
    """The filter's own health from its answers: supervisor resets (RESULT.flags, ERROR DIVERGED, STATS),
    restarts after measurement gaps (RESULT.flags GAP_RESTART, not divergences) and the longest gap,
    non-finite estimates, and signs that P is not positive definite (a variance <= 0, or S below R: the
    wire carries only P's diagonal, and S = H P H^T + R < R means H P H^T < 0)."""
    res = run.results[run.results["outcome"] == OUTCOME_RESULT]
    flags = res["flags"].astype(np.int64)
    var = np.stack([res[f"var_{k}"] for k in ("x", "y", "z", "vx", "vy", "vz", "d0", "d1", "d2")], axis=1)
    est = np.stack([res[k] for k in ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")], axis=1)
    finite = np.all(np.isfinite(est), axis=1) & np.all(np.isfinite(var), axis=1)
    r_var = np.zeros(len(res))
    for kind in KINDS.values():
        r_var[res["kind"] == kind.code] = kind.std(run.config) ** 2
    if run.config.stages & Stage.NN_STD:   # R is the network's std, unknown here; S > 0 is still required
        r_var = np.zeros(len(res))
    # geometry and baseline rejections are answered before the model: they carry S = 0
    answered = (res["status"] != Status.REJECTED_GEOMETRY) & (res["status"] != Status.REJECTED_BASELINE)
    s_low = (res["innovation_var"] < r_var * (1 - 1e-3)) | (res["innovation_var"] <= 0)
    not_pd = (np.any(var <= 0, axis=1) | (answered & s_low)) & finite
    from_errors = sum(1 for e in run.errors if e.code == ErrorCode.DIVERGED)
    # STATS counts from power-up: a device that flew earlier runs (a campaign flies every configuration of a
    # flight on one device) carries their resets, so take the difference over this run where it is known.
    from_stats = int(getattr(run.stats, "divergences", 0)) if run.stats is not None else 0
    if run.stats is not None and run.stats_start is not None:
        from_stats -= int(getattr(run.stats_start, "divergences", 0))
    reasons = {name: int(np.count_nonzero(flags & bit))
               for name, bit in (("non_finite", ResultFlag.NON_FINITE), ("out_of_box", ResultFlag.OUT_OF_BOX),
                                 ("speed", ResultFlag.SPEED), ("covariance", ResultFlag.COVARIANCE))
               if np.any(flags & bit)}
    t_all = np.sort(run.results["t_us"].astype(np.int64))
    return {"divergences": max(from_errors, from_stats, int(np.count_nonzero(flags & ResultFlag.DIVERGED))),
            "divergence_reasons": ", ".join(f"{k} {v}" for k, v in reasons.items()),
            # restarts after a measurement gap (GAP_RESTART): reported, not divergences
            "gap_restarts": int(np.count_nonzero(flags & ResultFlag.GAP_RESTART)),
            "longest_gap_s": float(np.max(np.diff(t_all))) / 1e6 if len(t_all) > 1 else 0.0,
            "non_finite": int(np.count_nonzero(~finite)), "not_pd": int(np.count_nonzero(not_pd)),
            "height_fused": int(np.count_nonzero(flags & ResultFlag.HEIGHT_FUSED))}


#: STATS counters of input frames the device refused (or could not read). The harness validates what it
#: sends, so in a run without injected faults each of them is a defect (of the link, the encoder or the device).
REFUSAL_COUNTERS = ("crc_errors", "framing_errors", "unknown_types", "bad_lengths", "non_finite", "unknown_anchors",
                    "time_backwards", "bad_configs", "bad_values")


def device_refusals(run: RunResult) -> dict[str, int] | None:
    """The refusal counters over this run (STATS after minus before; None when the start is unknown)."""
    if run.stats is None or run.stats_start is None:
        return None
    return {c: int(getattr(run.stats, c)) - int(getattr(run.stats_start, c)) for c in REFUSAL_COUNTERS}


def run_summary(run: RunResult, flight: Flight, budget_s: float = DEFAULT_BUDGET_S,
                cost_unit: int = 0, vdop_threshold: float = 5.0) -> dict[str, object]:
    """Everything a report or `--json` needs about one run. In windowed pacing the round trip includes
    the time a measurement waited behind the others in flight: its "deadline misses" are queueing, so
    they are reported as `over_budget_queued` and only lockstep/realtime pacing counts RTT misses."""
    from harness.report.geometry import geometry_summary
    res = run.results
    ok = res["outcome"] == OUTCOME_RESULT
    rtt_us = (res["t_recv_ns"][ok] - res["t_send_ns"][ok]) / 1e3
    compute = res["compute"][ok].astype(np.float64)
    if cost_unit == CostUnit.NANOSECONDS:
        compute_summary = latency_summary(compute / 1e3, budget_s * 1e6)   # ns -> us
    else:
        compute_summary = latency_summary(compute, budget_s * 168e6 / 2.0)  # instructions, ~2 CPI at 168 MHz
    stats = run.stats
    rtt_summary = latency_summary(rtt_us, budget_s * 1e6).as_dict()
    queued = run.pacing.mode == "windowed"
    rtt_misses = rtt_summary["deadline_misses"]
    if queued:
        rtt_summary["over_budget_queued"] = rtt_misses
        rtt_summary["deadline_misses"] = None
    return {
        "flight": run.flight,
        "pacing": run.pacing.mode,
        "stages": run.config.stages,
        "measurements": int(len(res)),
        "results": int(np.count_nonzero(ok)),
        "refused": int(np.count_nonzero(res["outcome"] == OUTCOME_ERROR)),
        "lost": int(np.count_nonzero(res["outcome"] == OUTCOME_LOST)),
        "accuracy": accuracy_summary(run, flight).as_dict(),
        "compute": compute_summary.as_dict(),
        "compute_unit": "us" if cost_unit == CostUnit.NANOSECONDS else "instructions",
        "round_trip_us": rtt_summary,
        "deadline_misses": int(compute_summary.deadline_misses) + (0 if queued else int(rtt_misses)),
        "health": health_summary(run),
        "geometry": geometry_summary(flight, vdop_threshold).as_dict(),
        "wall_s": run.wall_s,
        "sim_s": run.sim_s,
        "realtime_factor": run.realtime_factor,
        "device_stats": asdict(stats) if stats is not None else None,
        "device_refusals": device_refusals(run),
        "faults_injected": run.faults_injected,
        "host_decoder_errors": asdict(run.decoder_errors),
    }
