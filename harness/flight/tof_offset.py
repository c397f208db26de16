"""The flow deck's ToF ranger against the motion capture, on Crazyflie uSD logs: where the ranger sits along the
body z axis from the vehicle's origin (cf_usd_flight.TOF_BODY), and how far its readings scatter, in flight and
on the floor. The ranger measures along the body's -z axis to the floor, so with the origin at height z and
the ranger at body z offset l (flow deck under the centre) a reading is r = z / R22 + l, R22 = cos(tilt):
the offset is the mean of r - z / R22 over the in-flight readings (origin above 0.4 m).

    python -m harness.flight.tof_offset LOG [LOG ...]      # docs/real-flights.md "The ToF ranger"
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.errors import InputError
from harness.flight.data import FLIGHT_ABOVE_M
from harness.flight.formats.cf_usd import read_usd_log
from harness.flight.formats.cf_usd_flight import POSE, TOF
from harness.flight.formats.common import quat_to_rotmat



@dataclass(frozen=True)
class TofResiduals:
    """One log: r - z / R22 [m] of its readings in flight and on the floor (origin below 0.1 m)."""

    name: str
    flight: np.ndarray
    floor: np.ndarray


def tof_residuals(path: Path) -> TofResiduals:
    """The ranger's readings minus the body origin's height along the body z axis, in flight and on the floor."""
    log = read_usd_log(path)
    if not log.count(TOF) or log.count(POSE) < 2:
        raise InputError(f"{path}: no {TOF} readings or no {POSE} (motion capture): nothing to measure")
    pose = log.events[POSE]
    tp = log.times[POSE].astype(np.float64)
    t = log.times[TOF].astype(np.float64)
    r = log.events[TOF]["range.zrange"].astype(np.float64) * 1e-3
    inside = (t >= tp[0]) & (t <= tp[-1]) & (r > 0.0)
    t, r = t[inside], r[inside]
    z = np.interp(t, tp, pose["locSrv.z"].astype(np.float64))
    q = np.stack([np.interp(t, tp, pose[f"locSrv.q{c}"].astype(np.float64)) for c in "wxyz"], axis=1)
    c = quat_to_rotmat(q / np.linalg.norm(q, axis=1, keepdims=True))[:, 2, 2]
    res = r - z / c
    return TofResiduals(path.name, res[z > FLIGHT_ABOVE_M], res[z < 0.1])


def body_offset(logs: list[Path]) -> tuple[float, list[TofResiduals]]:
    """The ranger's body z offset [m]: the mean in-flight residual over all the logs' readings."""
    per_log = [tof_residuals(p) for p in logs]
    return float(np.mean(np.concatenate([p.flight for p in per_log]))), per_log


def describe(p: TofResiduals) -> str:
    floor = f"mean {p.floor.mean():+.4f} m" if p.floor.size else "none"
    return (f"{p.name:<14} in flight {p.flight.size:5d} readings, mean {p.flight.mean():+.4f} std "
            f"{p.flight.std():.4f} m; on the floor {p.floor.size:4d}, {floor}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", type=Path, help="Crazyflie uSD logs with estTOF and estPose")
    args = ap.parse_args(argv)
    try:
        offset, per_log = body_offset(args.logs)
    except (InputError, OSError) as exc:
        print(f"tof_offset: error: {exc}", file=sys.stderr)
        return 2
    print("\n".join([*(describe(p) for p in per_log),
                     f"ranger body z offset (mean in flight over {len(per_log)} logs): {offset:+.4f} m"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
