"""The phases of a run and the firmware's attitude error against the truth.

A real log has a ground phase (before take-off, after landing: the tag a few centimetres above the floor,
the anchors' lowest row at 0.2 m), where the UWB geometry says little about height. A measurement belongs
to the ground phase when the true tag height at its time (truth z, in the anchors' frame) is below
`flight_above` (default 0.4 m), to the flight phase otherwise. A run with no answered measurement below it
(every simulated flight of the harness) has one phase: `accuracy` carries no `phases` then.

The attitude error compares the attitude the firmware estimated (RESULT qw..qz, body -> world) with the
truth's (Truth.quat) at the measurement's time: the total angle of the rotation between them, and the
roll, pitch and yaw differences (the firmware's Euler formulas, wrapped to +-180 deg). It is what the bias
network is fed at run time, so its error is what a user needs to judge the network's inputs. A UWB-only
replay (constant-velocity model) keeps a level attitude and has no attitude estimate to report.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from harness.config import MODE_UWB_ONLY
from harness.flight.data import FLIGHT_ABOVE_M, Flight
from harness.flight.trajectory import quat_to_euler
from harness.report.metrics import accuracy_of, position_errors
from harness.stream.results_file import OUTCOME_RESULT
from harness.stream.streamer import RunResult

#: truth z [m] below which a measurement belongs to the ground phase (`--flight-above`)
DEFAULT_FLIGHT_ABOVE_M = FLIGHT_ABOVE_M

PHASES = ("flight", "ground")


def on_ground(flight: Flight, t_us: np.ndarray, flight_above: float) -> np.ndarray:
    """(N,) bool: the true tag height at these times is below `flight_above`."""
    z = np.interp(np.asarray(t_us, dtype=np.float64), flight.truth.t_us.astype(np.float64), flight.truth.pos[:, 2])
    return np.asarray(z < flight_above)


def add_phases(summary: dict[str, Any], run: RunResult, flight: Flight,
               flight_above: float = DEFAULT_FLIGHT_ABOVE_M) -> None:
    """Into a run summary (metrics.run_summary): `accuracy.phases` and `accuracy.flight_above` when the run
    has a ground phase, and `attitude` when there is an attitude error to report."""
    phases = phase_accuracy(run, flight, flight_above)
    if phases is not None:
        summary["accuracy"].update(flight_above=float(flight_above), phases=phases)
    attitude = attitude_summary(run, flight, flight_above)
    if attitude is not None:
        summary["attitude"] = attitude


def phase_accuracy(run: RunResult, flight: Flight,
                   flight_above: float = DEFAULT_FLIGHT_ABOVE_M) -> dict[str, dict[str, Any]] | None:
    """{flight, ground}: the accuracy (metrics.accuracy_of, the whole run's fields) of each phase; None when
    no answered measurement lies in the ground phase (the run has one phase)."""
    t_us, err = position_errors(run, flight)
    ground = on_ground(flight, t_us, flight_above)
    if not np.any(ground):
        return None
    status = run.results["status"][run.results["outcome"] == OUTCOME_RESULT]
    return {name: accuracy_of(err[sel], status[sel]).as_dict() for name, sel in zip(PHASES, (~ground, ground))}


def quat_angle_deg(q_true: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """(N,) angle [deg] of the rotation from q_true to q_est ((N, 4) w, x, y, z each; either sign)."""
    a = q_true / np.linalg.norm(q_true, axis=1, keepdims=True)
    b = q_est / np.linalg.norm(q_est, axis=1, keepdims=True)
    w = np.sum(a * b, axis=1)          # conj(a) * b: scalar part a.b, vector part aw bv - bw av - av x bv
    v = a[:, :1] * b[:, 1:] - b[:, :1] * a[:, 1:] - np.cross(a[:, 1:], b[:, 1:])
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(v, axis=1), np.abs(w)))


def euler_errors_deg(q_true: np.ndarray, q_est: np.ndarray) -> np.ndarray:
    """(N, 3) roll, pitch, yaw of the estimate minus the truth's [deg], wrapped to [-180, 180)."""
    d = np.degrees(quat_to_euler(q_est / np.linalg.norm(q_est, axis=1, keepdims=True))
                   - quat_to_euler(q_true / np.linalg.norm(q_true, axis=1, keepdims=True)))
    return (d + 180.0) % 360.0 - 180.0


def attitude_stats(angle: np.ndarray, euler: np.ndarray) -> dict[str, Any]:
    """n, angle_p50_deg / angle_p95_deg (total angle), and <axis>_mean_deg / <axis>_rms_deg per Euler angle."""
    nan = float("nan")
    out: dict[str, Any] = {"n": int(len(angle))}
    p50, p95 = np.percentile(angle, [50, 95]) if len(angle) else (nan, nan)
    out["angle_p50_deg"], out["angle_p95_deg"] = float(p50), float(p95)
    for k, axis in enumerate(("roll", "pitch", "yaw")):
        col = euler[:, k]
        out[f"{axis}_mean_deg"] = float(np.mean(col)) if len(col) else nan
        out[f"{axis}_rms_deg"] = float(np.sqrt(np.mean(col ** 2))) if len(col) else nan
    return out


def attitude_errors(run: RunResult, flight: Flight,
                    block: int = 1 << 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_us, total angle [deg], (N, 3) roll/pitch/yaw errors [deg]) of every RESULT with a finite, non-zero
    quaternion; in blocks of rows, so a 1-hour run's summary holds no (N, 4) temporaries."""
    res = run.results
    idx = np.flatnonzero(res["outcome"] == OUTCOME_RESULT)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for i in range(0, len(idx), block):
        rows = idx[i:i + block]
        q_est = np.stack([res[k][rows] for k in ("qw", "qx", "qy", "qz")], axis=1).astype(np.float64)
        good = np.all(np.isfinite(q_est), axis=1) & (np.linalg.norm(q_est, axis=1) > 0)
        t_us, q_est = res["t_us"][rows][good].astype(np.int64), q_est[good]
        q_true = flight.truth.quat_at(t_us)
        parts.append((t_us, quat_angle_deg(q_true, q_est), euler_errors_deg(q_true, q_est)))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]))


def attitude_summary(run: RunResult, flight: Flight,
                     flight_above: float = DEFAULT_FLIGHT_ABOVE_M) -> dict[str, Any] | None:
    """The firmware's attitude (RESULT qw..qz) against the truth's, over the run and (with a ground phase)
    per phase; None when the truth has no attitude or the replay is UWB-only (no attitude estimated)."""
    if flight.truth.quat is None or run.config.mode == MODE_UWB_ONLY:
        return None
    t_us, angle, euler = attitude_errors(run, flight)
    out = attitude_stats(angle, euler)
    ground = on_ground(flight, t_us, flight_above)
    if np.any(ground):
        out["phases"] = {name: attitude_stats(angle[sel], euler[sel]) for name, sel in zip(PHASES, (~ground, ground))}
    return out
