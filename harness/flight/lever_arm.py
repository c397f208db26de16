"""Tag lever-arm calibration: where the UWB antenna's phase centre sits in the body frame of a vehicle whose pose
the motion capture gives (the origin of its marker set), fitted on recordings with attitude.

Ground truth of a recorded flight is the mocap pose moved to the tag by a lever arm (harness/flight/formats/
cf_usd_flight.py, util.py). When the assumed lever arm is off by `d` (body frame), every measurement's error
against that truth carries `H R d` (H: the measurement's gradient at the tag, R: body -> world), a position-
dependent bias that the filter turns into a constant offset of its estimate. The fit is the least-squares `d`
over the measurements taken in flight (truth above `flight_above`, the ground phase's NLOS excluded) with
|error| < `xi` (outliers are the gates' business); the calibrated lever arm is the assumed one plus `d`.
On the Crazyflie uSD logs of 0425 it is about (+0.05, -0.02, +0.07) m off UTIL's lever arm: the 0.05-0.10 m by
which the estimate sat high in flight (docs/real-flights.md).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.errors import InputError
from harness.flight.data import FLIGHT_ABOVE_M, Flight
from harness.kinds import kind_of
from harness.options import MAX_LEVER_ARM_M
from harness.flight.formats.common import quat_to_rotmat

XI_M = 0.7


@dataclass(frozen=True)
class LeverArmFit:
    """A fitted lever arm and where it came from."""

    lever_arm_m: tuple[float, float, float]     # calibrated: assumed + correction
    assumed_m: tuple[float, float, float]       # the lever arm the flights were read with
    correction_m: tuple[float, float, float]
    measurements: int
    fitted_on: tuple[str, ...]
    per_flight_m: dict[str, tuple[float, float, float]]   # the correction each flight alone gives

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def _rows(flight: Flight, flight_above: float, xi: float) -> tuple[np.ndarray, np.ndarray]:
    """(H R (n, 3), error (n,)) of the flight's in-flight measurements."""
    u, tr = flight.uwb, flight.truth
    if tr.quat is None or u.true_value is None:
        raise InputError(f"{flight.name}: a lever-arm fit needs the truth's attitude and the true values")
    p = tr.position_at(u.t_us)
    err = u.value - u.true_value
    keep = (p[:, 2] > flight_above) & (np.abs(err) < xi)
    if not keep.any():
        return np.zeros((0, 3)), np.zeros(0)
    p, err = p[keep], err[keep]
    pos = flight.anchors.as_dict()
    a = np.array([pos[int(i)] for i in u.anchor_a[keep]])
    da = (p - a) / np.linalg.norm(p - a, axis=1, keepdims=True)
    if kind_of(u.kind).n_anchors == 2:
        b = np.array([pos[int(i)] for i in u.anchor_b[keep]])
        grad = (p - b) / np.linalg.norm(p - b, axis=1, keepdims=True) - da
    else:
        grad = da
    rot = quat_to_rotmat(tr.quat_at(u.t_us[keep]))
    return np.einsum("ni,nij->nj", grad, rot), err


def _solve(rows: np.ndarray, err: np.ndarray) -> tuple[float, float, float]:
    d = np.linalg.lstsq(rows, err, rcond=None)[0]
    return (float(d[0]), float(d[1]), float(d[2]))


def fit_lever_arm(flights: Sequence[Flight], flight_above: float = FLIGHT_ABOVE_M, xi: float = XI_M) -> LeverArmFit:
    """The lever arm that best explains the flights' measurement errors (all read with the same lever arm)."""
    if not flights:
        raise InputError("a lever-arm fit needs at least one recording")
    without = [f.name for f in flights if "tag_lever_arm_m" not in f.meta]
    if without:     # rcv_twr: the motion capture tracks the tag itself, there is no lever arm to fit
        raise InputError(f"{', '.join(without)}: no tag lever arm in this recording (its truth is not the vehicle "
                         "body's pose): a lever-arm fit needs the body's pose and attitude, as in Crazyflie uSD logs")
    assumed = {tuple(np.round(f.meta["tag_lever_arm_m"], 9)) for f in flights}
    if len(assumed) != 1 or any(v != v for v in next(iter(assumed))):
        raise InputError("the recordings were read with different (or no) lever arms: read them all with one "
                         f"--lever-arm (found {sorted(assumed)})")
    parts = {f.name: _rows(f, flight_above, xi) for f in flights}
    rows = np.concatenate([r for r, _ in parts.values()])
    err = np.concatenate([e for _, e in parts.values()])
    if rows.shape[0] < 100:
        raise InputError(f"only {rows.shape[0]} in-flight measurements (truth above {flight_above} m, |error| < "
                         f"{xi} m): too few to fit a lever arm")
    corr = _solve(rows, err)
    base = tuple(float(v) for v in next(iter(assumed)))
    lever = (base[0] + corr[0], base[1] + corr[1], base[2] + corr[2])
    per_flight = {name: _solve(r, e) for name, (r, e) in parts.items() if r.shape[0] >= 100}
    return LeverArmFit(lever_arm_m=lever, assumed_m=(base[0], base[1], base[2]), correction_m=corr,
                       measurements=int(rows.shape[0]), fitted_on=tuple(f.name for f in flights),
                       per_flight_m=per_flight)


def save_lever_arm(fit: LeverArmFit, path: Path) -> Path:
    path.write_text(json.dumps(fit.as_dict(), indent=2) + "\n")
    return path


def load_lever_arm(path: Path) -> tuple[float, float, float]:
    """The calibrated lever arm of a file written by save_lever_arm (`uwb-hil lever-arm --out`)."""
    try:
        data = json.loads(Path(path).read_text())
        x, y, z = (float(v) for v in data["lever_arm_m"])
    except FileNotFoundError:
        raise InputError(f"lever-arm file {path} not found") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a lever-arm calibration (expected JSON with lever_arm_m = [x, y, z]): "
                         f"{str(exc)[:100]}") from None
    if not all(np.isfinite([x, y, z])):
        raise InputError(f"{path}: lever_arm_m must be finite")
    if max(abs(x), abs(y), abs(z)) > MAX_LEVER_ARM_M:      # as --lever-arm X,Y,Z: a value in mm is refused
        raise InputError(f"{path}: lever_arm_m ({x:g}, {y:g}, {z:g}) has a component beyond +-{MAX_LEVER_ARM_M:g} m "
                         "(millimetres instead of metres?)")
    return (x, y, z)
