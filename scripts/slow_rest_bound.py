"""How far position accuracy could go if the slowly varying part of the UWB error were removed.

    python scripts/slow_rest_bound.py RECORDING... --anchors ANCHORS.csv [--window 0.25]

Replays each recording through the numpy twin (UWB-only, outlier rejection) twice: as recorded, and with
every measurement minus the slow part of its true error (the error's moving average over +-window s per
anchor pair: what the ceiling of harness/biasnet/ceiling.py counts as removable; errors >= 0.7 m are left
in, they are outliers). Prints both position RMSEs. Truth is used: a bound, not a method.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.biasnet.ceiling import HALF_WINDOW_S, moving_average
from harness.biasnet.dataset import XI_DEFAULT, geometric_value
from harness.biasnet.recipes import load_recordings
from harness.config import PRESETS
from harness.flight.data import Flight
from harness.flight.run_config import config_for
from harness.twin.estimator import run_flight


def without_slow_error(flight: Flight, half_window_s: float) -> Flight:
    u = flight.uwb
    err = np.asarray(u.value, dtype=np.float64) - geometric_value(flight, flight.truth.position_at(u.t_us))
    err = np.where(np.abs(err) < XI_DEFAULT, err, 0.0)
    keys = np.asarray(u.anchor_a, dtype=np.int64) * 4096 + np.asarray(u.anchor_b, dtype=np.int64)
    slow = np.zeros_like(err)
    for k in np.unique(keys):
        m = keys == k
        slow[m] = moving_average(u.t_us[m] * 1e-6, err[m], half_window_s)
    return replace(flight, uwb=replace(u, value=np.asarray(u.value, dtype=np.float64) - slow))


def position_rmse(flight: Flight) -> float:
    cfg = config_for(flight, stages=PRESETS["outlier"], uwb_only=True)
    pos = np.array([r.pos for r in run_flight(flight, cfg)])
    t = flight.uwb.t_us
    ok = (t >= flight.truth.t_us[0]) & (t <= flight.truth.t_us[-1])
    return float(np.sqrt(np.mean(np.sum((pos[ok] - flight.truth.position_at(t[ok])) ** 2, axis=1))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recordings", type=Path, nargs="+")
    ap.add_argument("--anchors", type=Path, default=None)
    ap.add_argument("--window", type=float, default=HALF_WINDOW_S, help="half width of the moving average [s]")
    args = ap.parse_args()
    for path, flight in zip(args.recordings, load_recordings(args.recordings, args.anchors)):
        print(f"{path.name}: as recorded {position_rmse(flight):.4f} m, "
              f"slow error removed {position_rmse(without_slow_error(flight, args.window)):.4f} m", flush=True)


if __name__ == "__main__":
    main()
