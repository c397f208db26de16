"""How the UTIL flights move, from their ground truth: is there a case for a per-axis process noise?

    python scripts/truth_motion.py RECORDING... [--rate 20]

Per recording: measurements per second, the truth's height range, and the RMS of the ground truth's velocity and acceleration per
axis (positions resampled at --rate Hz, central differences). The UWB-only CV model's process noise is one
white-acceleration std for all axes (proc_cv_acc); docs/bias-network.md, "Filter settings ...".
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.biasnet.recipes import load_recordings


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recordings", type=Path, nargs="+")
    ap.add_argument("--anchors", type=Path, default=None)
    ap.add_argument("--rate", type=float, default=20.0, help="resampling rate of the truth [Hz]")
    args = ap.parse_args()
    dt = 1.0 / args.rate
    for path, flight in zip(args.recordings, load_recordings(args.recordings, args.anchors)):
        t = flight.truth.t_us
        tt = np.arange(t[0], t[-1], dt * 1e6)
        p = flight.truth.position_at(tt)
        v = np.gradient(p, dt, axis=0)
        a = np.gradient(v, dt, axis=0)
        rate = len(flight.uwb.t_us) / ((flight.uwb.t_us[-1] - flight.uwb.t_us[0]) * 1e-6)
        rms = lambda x: " ".join(f"{s:.3f}" for s in np.sqrt(np.mean(x ** 2, axis=0)))  # noqa: E731
        z = flight.truth.position_at(t)[:, 2]
        print(f"{path.name}: {rate:.0f} meas/s, z {z.min():.2f}-{z.max():.2f} m, below 0.5 m "
              f"{100 * np.mean(p[:, 2] < 0.5):.0f} % of the time, velocity RMS x y z {rms(v)} m/s, acceleration RMS x y z {rms(a)} m/s^2")


if __name__ == "__main__":
    main()
