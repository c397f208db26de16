"""Is a loaded recording plausible? Syntax checks (formats/) cannot see a file written in the wrong units or
with a broken anchor survey: such a file loads, replays and yields a confident, meaningless RMSE. These
checks look at what the numbers mean (anchor geometry, pose range, time rate, measurement error against
the truth, pose/measurement time overlap) and name the likely cause ("looks like millimetres").

`check_recording(flight, path)` raises `ImplausibleRecording` (a RecordingError, exit code 2 in the CLI)
with every finding; `findings(flight)` lists them without raising. `--force` skips the check.
The thresholds are deliberately loose (a factor of ~10 from every shared recording, see
tests/unit/test_plausibility.py): they catch unit and survey mistakes, not noisy data.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.flight.formats.common import RecordingError
from harness.flight.data import KIND_TWR, Flight
from harness.kinds import kind_of


@dataclass(frozen=True)
class Limits:
    """Plausible ranges for a UWB flight recording (SI units). UWB radios reach ~100 m."""

    max_anchor_spread_m: float = 300.0     # largest anchor-anchor distance
    min_anchor_spread_m: float = 0.2       # below this, "all anchors at one point"
    min_anchor_separation_m: float = 0.01  # two anchors closer than this are the same point
    min_off_line_m: float = 0.005          # rms distance of the anchors from their best-fit line (2nd
                                           # singular value / sqrt(n)); rcv_twr sequence 2 has 0.014 m
    max_pose_distance_m: float = 300.0     # truth position from the anchors' centre
    max_measurement_m: float = 300.0       # |range| or |TDoA| (median)
    min_rate_hz: float = 1.0               # UWB measurements per second (times in ms look 1000x slower)
    max_rate_hz: float = 100_000.0
    max_gross_share: float = 0.5           # |value - true value| >= gross_m
    gross_m: float = 1.0                   # the loaders' gross-error threshold (error_summary core_m)
    min_time_overlap: float = 0.8          # share of the UWB time span covered by the truth
    max_gap_share: float = 0.5             # longest pause of the UWB stream / its span (rcv_twr: 14 s of 168)
    min_gap_s: float = 60.0                # ... when longer than this (a realtime replay waits it out)
    min_samples: int = 20                  # rate / share checks need this many measurements
    min_acc_median: float = 3.0            # median |specific force| [m/s^2] of a flight is ~g (9.81)
    max_acc_median: float = 30.0
    max_gyro_p99: float = 20.0             # 99th percentile |body rate| [rad/s] (1150 deg/s; shared logs <= 1.6)


class ImplausibleRecording(RecordingError):
    """The recording loads but its content cannot be right (units, geometry, time base)."""

    def __init__(self, problems: list[str], *, path: Path | str | None = None) -> None:
        self.problems = list(problems)
        text = "implausible recording: " + "; ".join(problems) + " (pass --force to replay it anyway)"
        super().__init__(text, path=path)


def findings(flight: Flight, limits: Limits = Limits()) -> list[str]:
    """Every implausibility found, each with its likely cause; empty when the recording looks sane."""
    return [*_anchor_findings(flight, limits), *_pose_findings(flight, limits),
            *_time_findings(flight, limits), *_measurement_findings(flight, limits), *_imu_findings(flight, limits)]


def figures(flight: Flight) -> dict[str, float]:
    """The quantities the checks look at (for `python -m harness.flight.loaders` and the docs' margins)."""
    u, tr = flight.uwb, flight.truth
    pos = _used_anchor_positions(flight)
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1) if len(pos) else np.zeros((1, 1))
    span_s = (int(u.t_us[-1]) - int(u.t_us[0])) * 1e-6 if len(u) > 1 else 0.0
    out = {"anchor_spread_m": float(d.max()),
           "anchor_min_separation_m": float(d[np.triu_indices(len(pos), 1)].min()) if len(pos) > 1 else float("nan"),
           "anchor_off_line_m": float(np.linalg.svd(pos - pos.mean(axis=0), compute_uv=False)[1]) / np.sqrt(len(pos))
           if len(pos) >= 3 else float("nan"),
           "pose_median_distance_m": float(np.median(np.linalg.norm(tr.pos - flight.anchors.positions.mean(axis=0),
                                                                    axis=1))) if len(tr.pos) else float("nan"),
           "rate_hz": (len(u) - 1) / span_s if span_s > 0 else float("nan"),
           "median_abs_value_m": float(np.median(np.abs(u.value))) if len(u) else float("nan")}
    if u.true_value is not None and len(u):
        out["gross_share"] = float(np.mean(~(np.abs(u.value - u.true_value) < Limits.gross_m)))
    if flight.imu is not None and len(flight.imu):
        out["acc_median_mps2"], out["gyro_p99_rads"] = _imu_figures(flight.imu.acc, flight.imu.gyro)
    return out


def _imu_figures(acc: np.ndarray, gyro: np.ndarray) -> tuple[float, float]:
    """Median |specific force| [m/s^2] and 99th percentile |body rate| [rad/s]: what the unit checks judge."""
    return (float(np.median(np.linalg.norm(acc, axis=1))),
            float(np.percentile(np.linalg.norm(gyro, axis=1), 99)))


def check_recording(flight: Flight, path: Path | str | None = None, limits: Limits = Limits()) -> None:
    problems = findings(flight, limits)
    if problems:
        raise ImplausibleRecording(problems, path=path)


def _looks_mm(value_m: float, upper_m: float) -> str:
    """The likely cause of a too-large length."""
    if 0.1 <= value_m / 1000.0 <= upper_m:
        return "looks like millimetres (expected metres)"
    return "not metres, or not one coordinate frame"


def _used_anchor_positions(flight: Flight) -> np.ndarray:
    u = flight.uwb
    used = set(np.unique(u.anchor_a).tolist())
    if u.kind != KIND_TWR:
        used |= set(np.unique(u.anchor_b).tolist())
    keep = np.array([int(i) in used for i in flight.anchors.ids]) if len(u) else np.ones(len(flight.anchors.ids), bool)
    return flight.anchors.positions[keep] if keep.any() else flight.anchors.positions


def _anchor_findings(flight: Flight, lim: Limits) -> list[str]:
    pos = _used_anchor_positions(flight)
    if len(pos) < 2:
        return []
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
    spread = float(d.max())
    if spread > lim.max_anchor_spread_m:
        return [f"anchors span {spread:.1f} m (more than {lim.max_anchor_spread_m:g} m): "
                f"{_looks_mm(spread, lim.max_anchor_spread_m)}"]
    if spread < lim.min_anchor_spread_m:
        return [f"all {len(pos)} anchors lie within {spread:.3f} m of each other (all at one point): "
                "the anchor survey is broken or in the wrong units"]
    out = []
    iu = np.triu_indices(len(pos), 1)
    close = np.nonzero(d[iu] < lim.min_anchor_separation_m)[0]
    if close.size:
        ids = flight.anchors.ids
        pairs = [f"{int(ids[iu[0][k]])}-{int(ids[iu[1][k]])}" for k in close[:4]] if len(ids) == len(pos) else []
        out.append(f"{close.size} pair(s) of anchors at the same position {' '.join(pairs)}".rstrip()
                   + ": coincident anchors (a copy-paste error in the survey?)")
    if len(pos) >= 3:
        off_line = float(np.linalg.svd(pos - pos.mean(axis=0), compute_uv=False)[1]) / np.sqrt(len(pos))
        if off_line < lim.min_off_line_m:
            out.append(f"the anchors lie on one line (rms {1000 * off_line:.1f} mm off it): a position cannot be "
                       "solved from them (a copy-paste error in the survey?)")
    return out


def _pose_findings(flight: Flight, lim: Limits) -> list[str]:
    pos = flight.truth.pos
    if len(pos) == 0:
        return []
    centre = flight.anchors.positions.mean(axis=0)
    dist = float(np.median(np.linalg.norm(pos - centre, axis=1)))
    if dist > lim.max_pose_distance_m:
        return [f"ground-truth poses are a median {dist:.1f} m from the anchors' centre (more than "
                f"{lim.max_pose_distance_m:g} m): {_looks_mm(dist, lim.max_pose_distance_m)}"]
    return []


def _time_findings(flight: Flight, lim: Limits) -> list[str]:
    u, tr = flight.uwb, flight.truth
    out = []
    if len(u) >= lim.min_samples:
        span_s = (int(u.t_us[-1]) - int(u.t_us[0])) * 1e-6
        rate = (len(u) - 1) / span_s if span_s > 0 else float("inf")
        if rate < lim.min_rate_hz:
            out.append(f"{len(u)} UWB measurements over {span_s:.0f} s ({rate:.3g} Hz, below "
                       f"{lim.min_rate_hz:g} Hz): the times look like milliseconds (expected seconds)")
        elif rate > lim.max_rate_hz:
            out.append(f"{len(u)} UWB measurements within {span_s * 1e6:.0f} us ({rate:.3g} Hz): the times look "
                       "like they are in a coarser unit than seconds (minutes? hours?)")
        gap_s = float(np.diff(np.asarray(u.t_us, dtype=np.int64)).max()) * 1e-6
        if gap_s > max(lim.min_gap_s, lim.max_gap_share * span_s):
            out.append(f"the UWB stream pauses for {gap_s:.0f} s of its {span_s:.0f} s: two flights in one file, "
                       "or a jump of the clock")
    dropped = flight.meta.get("dropped", {})
    outside = sum(int(v) for k, v in dropped.items() if k.endswith("_outside_truth_span")) \
        if isinstance(dropped, dict) else 0
    if outside and len(u) / (len(u) + outside) < lim.min_time_overlap:
        # the loaders drop measurements outside the truth's time span: count those as not overlapping
        out.append(f"only {100 * len(u) / (len(u) + outside):.0f} % of the measurements fall within the ground-truth "
                   f"poses' time span ({outside} dropped): the two streams use different clocks or time units")
    elif len(u) >= 2 and len(tr.t_us) >= 2:
        u0, u1 = int(u.t_us[0]), int(u.t_us[-1])
        t0, t1 = int(tr.t_us[0]), int(tr.t_us[-1])
        overlap = max(0, min(u1, t1) - max(u0, t0)) / max(u1 - u0, 1)
        if overlap < lim.min_time_overlap:
            out.append(f"the ground-truth poses cover {100 * overlap:.0f} % of the measurements' time span "
                       f"(measurements {u0 * 1e-6:.3f}..{u1 * 1e-6:.3f} s, poses {t0 * 1e-6:.3f}..{t1 * 1e-6:.3f} s):"
                       " the two streams use different clocks or time units")
    return out


def _measurement_findings(flight: Flight, lim: Limits) -> list[str]:
    u = flight.uwb
    if len(u) == 0:
        return []
    med = float(np.median(np.abs(u.value)))
    if med > lim.max_measurement_m:
        what = kind_of(u.kind).value_name
        return [f"median |{what}| is {med:.1f} m (more than {lim.max_measurement_m:g} m): "
                f"{_looks_mm(med, lim.max_measurement_m)}"]
    if u.true_value is None or len(u) < lim.min_samples:
        return []
    err = np.abs(u.value - u.true_value)
    share = float(np.mean(~(err < lim.gross_m)))        # NaN counts as gross
    if share > lim.max_gross_share:
        return [f"{100 * share:.0f} % of the measurements differ from the ground truth by {lim.gross_m:g} m or "
                f"more (gross errors; at most {100 * lim.max_gross_share:.0f} % expected): the anchors, poses or "
                "measurements are in different units or frames, or the anchors belong to another constellation"]
    return []


def _imu_findings(flight: Flight, lim: Limits) -> list[str]:
    """Accelerometer in m/s^2 (a file in g gives ~1) and gyro in rad/s (in deg/s its fast turns exceed any
    real body rate)."""
    imu = flight.imu
    if imu is None or len(imu) < lim.min_samples:
        return []
    out = []
    acc, rate = _imu_figures(imu.acc, imu.gyro)
    if not lim.min_acc_median <= acc <= lim.max_acc_median:
        cause = "looks like g (expected m/s^2)" if 0.3 <= acc <= 3.0 else "not m/s^2"
        out.append(f"median |acceleration| is {acc:.3g} m/s^2 (expected ~9.81, within {lim.min_acc_median:g}.."
                   f"{lim.max_acc_median:g}): {cause}")
    if rate > lim.max_gyro_p99:
        out.append(f"99th percentile |body rate| is {rate:.3g} rad/s (more than {lim.max_gyro_p99:g}): looks like "
                   "deg/s (expected rad/s)")
    return out
