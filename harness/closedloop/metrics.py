"""Closed-loop figures of one flight and of a campaign (the paper's Fig. 8 and its take-off claim).

Per flight (from the control-step log):
  tracking error  e_t = |p_true - p_commanded|; RMSE over the trajectory proper (take-off and landing
                  excluded: `tracking_rmse`) and over the whole airborne span (`tracking_rmse_flight`);
  estimation error e = |p_estimate - p_true| over the airborne span (`estimation_rmse`);
  take-off        success iff, within `TakeoffRule.window_s` of the take-off command, the true height
                  reaches `height_m` while the tilt stays <= `max_tilt_deg` and the horizontal distance
                  from the take-off point stays <= `max_drift_m` (and the safety monitor did not abort);
  completed       the safety monitor never aborted the flight.
A campaign aggregates seeds per (mode, mission, configuration): mean and std over the completed flights,
take-off successes k/N, and RMSE-over-seeds of e_t against time (Fig. 8's curves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.closedloop.cosim import FlightLog
from protocol.messages import ControlFlag


@dataclass(frozen=True)
class TakeoffRule:
    window_s: float = 3.0
    height_m: float = 0.5
    max_tilt_deg: float = 30.0
    max_drift_m: float = 0.5


def tilt_deg(q: np.ndarray) -> np.ndarray:
    c = 1.0 - 2.0 * (q[:, 1] ** 2 + q[:, 2] ** 2)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _rmse(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def takeoff(log: FlightLog, rule: TakeoffRule = TakeoffRule()) -> dict[str, Any]:
    ph = log.meta["phases"]
    t0 = float(ph["t_takeoff"])
    win = (log.t >= t0 - 1e-9) & (log.t <= t0 + rule.window_s + 1e-9)
    out: dict[str, Any] = {"success": False, "t_reach_s": None, "max_tilt_deg": float("nan"),
                           "max_drift_m": float("nan"), "reason": ""}
    if not np.any(win):
        out["reason"] = "the flight ended before take-off"
        return out
    z = log.p_true[win, 2]
    reached = np.nonzero(z >= rule.height_m)[0]
    tilt = tilt_deg(log.q_true[win])
    drift = np.linalg.norm(log.p_true[win, :2] - log.p_cmd[win][:1, :2], axis=1)
    out["max_tilt_deg"] = float(np.max(tilt))
    out["max_drift_m"] = float(np.max(drift))
    if reached.size:
        out["t_reach_s"] = float(log.t[win][reached[0]] - t0)
    aborted_in = log.aborted is not None and log.abort_t is not None and log.abort_t <= t0 + rule.window_s
    reasons = []
    if not reached.size:
        reasons.append(f"did not reach {rule.height_m} m within {rule.window_s} s (max {float(np.max(z)):.2f} m)")
    if out["max_tilt_deg"] > rule.max_tilt_deg:
        reasons.append(f"tilt {out['max_tilt_deg']:.0f} deg > {rule.max_tilt_deg:.0f}")
    if out["max_drift_m"] > rule.max_drift_m:
        reasons.append(f"drift {out['max_drift_m']:.2f} m > {rule.max_drift_m}")
    if aborted_in:
        reasons.append(f"aborted: {log.aborted}")
    out["success"] = not reasons
    out["reason"] = "; ".join(reasons)
    return out


def flight_metrics(log: FlightLog, rule: TakeoffRule = TakeoffRule()) -> dict[str, Any]:
    ph = log.meta["phases"]
    e_t = np.linalg.norm(log.p_true - log.p_cmd, axis=1)
    e_est = np.linalg.norm(log.p_est - log.p_true, axis=1)
    main = (log.t >= ph["t_main0"]) & (log.t <= ph["t_main1"])
    air = (log.t >= ph["t_takeoff"]) & (log.t <= ph["t_land"])
    completed = log.aborted is None
    return {
        "completed": completed,
        "aborted": log.aborted,
        "abort_t": log.abort_t,
        "takeoff": takeoff(log, rule),
        # a flight that did not finish its trajectory has no tracking figure for it
        "tracking_rmse": _rmse(e_t[main]) if completed else float("nan"),
        "tracking_max": float(np.max(e_t[main])) if completed and np.any(main) else float("nan"),
        "tracking_rmse_flight": _rmse(e_t[air]),
        "estimation_rmse": _rmse(e_est[air]),
        "estimation_rmse_xy": _rmse(np.linalg.norm(log.p_est[air, :2] - log.p_true[air, :2], axis=1)),
        "estimation_rmse_z": _rmse(log.p_est[air, 2] - log.p_true[air, 2]),
        "max_tilt_deg": float(np.max(tilt_deg(log.q_true[air]))) if np.any(air) else float("nan"),
        "statuses": dict(log.statuses),
        "nlos_events": log.nlos_events,
        "device_errors": len(log.errors),
        "control_flags": {flag.name.lower(): int(np.count_nonzero(log.flags[air] & flag)) for flag in ControlFlag},
        "duration_s": float(log.t[-1]) if log.n else 0.0,
        "wall_s": log.wall_s,
        "late_controls": log.late_controls,
    }


def _mean_std(values: list[float]) -> tuple[float, float]:
    v = np.array([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return float("nan"), float("nan")
    return float(np.mean(v)), float(np.std(v))


def aggregate(logs: list[FlightLog], metrics: list[dict[str, Any]], series_dt: float = 0.1) -> dict[str, Any]:
    """Seeds of one (mode, mission, configuration) cell."""
    n = len(metrics)
    tr_m, tr_s = _mean_std([m["tracking_rmse"] for m in metrics])
    es_m, es_s = _mean_std([m["estimation_rmse"] for m in metrics])
    esz_m, _ = _mean_std([m["estimation_rmse_z"] for m in metrics])
    # e_t against time, RMS over the seeds still flying at that time (Fig. 8), on a coarse grid
    series: dict[str, list[float]] = {"t": [], "rmse": [], "std": [], "n": []}
    if logs:
        t_end = max(float(lg.t[-1]) for lg in logs if lg.n)
        grid = np.arange(0.0, t_end + 1e-9, series_dt)
        rows = []
        for lg in logs:
            e = np.linalg.norm(lg.p_true - lg.p_cmd, axis=1)
            idx = np.searchsorted(lg.t, grid)
            ok = idx < lg.n
            v = np.full(grid.shape, np.nan)
            v[ok] = e[idx[ok]]
            rows.append(v)
        arr = np.array(rows)
        cnt = np.sum(np.isfinite(arr), axis=0)
        with np.errstate(invalid="ignore"):
            rms = np.sqrt(np.nanmean(arr ** 2, axis=0)) if arr.size else np.zeros(0)
            std = np.nanstd(arr, axis=0)
        series = {"t": np.round(grid, 3).tolist(), "rmse": np.round(rms, 4).tolist(),
                  "std": np.round(std, 4).tolist(), "n": cnt.astype(int).tolist()}
    return {
        "flights": n,
        "completed": sum(1 for m in metrics if m["completed"]),
        "takeoff_success": sum(1 for m in metrics if m["takeoff"]["success"]),
        "tracking_rmse_mean": tr_m, "tracking_rmse_std": tr_s,
        "tracking_rmse_max": max((m["tracking_rmse"] for m in metrics if math.isfinite(m["tracking_rmse"])),
                                 default=float("nan")),
        "estimation_rmse_mean": es_m, "estimation_rmse_std": es_s, "estimation_rmse_z_mean": esz_m,
        "takeoff_failures": [m["takeoff"]["reason"] for m in metrics if not m["takeoff"]["success"]],
        "aborts": [m["aborted"] for m in metrics if m["aborted"]],
        "series": series,
    }
