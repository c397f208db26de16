"""`make bench` (real-flight replay): one shared Crazyflie uSD flight (IMU ~1 kHz + TDoA) replayed through
the host build and through the STM32F405 build under QEMU, the same command line for both
(`uwb-hil run --recording LOG --stages outlier --json`, windowed pacing).

    python -m harness.bench.real_replay [--recording LOG] [--json]

Figures: flight seconds over wall seconds (x real time) per target, the QEMU/host ratio measured in the
same run, and the link traffic the replay needs per flight second (the bytes `uwb-hil run` writes: every
IMU sample and UWB measurement as a frame). Under QEMU the link, not the guest's arithmetic, sets the pace
(QEMU moves one byte per main-loop iteration, docs/qemu.md), so the bytes per wall second it reaches are
printed as well. The two replays' flight RMSE must agree (same firmware core).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from harness.paths import shared_data_dir
from harness.report.replay_all import run_json

DEFAULT_FLIGHT = Path("cf_usd") / "0425" / "0425-traj3"
TARGETS = ("host", "qemu")


@dataclass(frozen=True)
class ReplayFigure:
    target: str
    flight_s: float
    wall_s: float
    realtime_factor: float
    link_bytes: int
    link_bytes_per_wall_s: float
    flight_rmse_m: float


def link_bytes(recording: Path) -> int:
    """The bytes the host writes for this recording (PreparedFlight.stream, as the streamer sends it)."""
    from harness.flight.loaders import load_recording
    from harness.stream.prepare import prepare
    return len(prepare(load_recording(recording), seq0=0).stream)


def replay(recording: Path, target: str, n_bytes: int, timeout_s: float) -> ReplayFigure:
    code, out, reason = run_json((str(recording), "--stages", "outlier", "--target", target), timeout_s)
    if out is None or "wall_s" not in out:
        raise RuntimeError(f"{target} replay of {recording.name} failed (exit {code}): {reason}")
    wall = float(out["wall_s"])
    return ReplayFigure(target, float(out["sim_s"]), wall, float(out["realtime_factor"]), n_bytes,
                        n_bytes / wall if wall > 0 else float("nan"),
                        float(out["accuracy"]["phases"]["flight"]["rmse"]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.bench.real_replay", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", type=Path, help=f"a Crazyflie uSD log (default: <data>/{DEFAULT_FLIGHT})")
    ap.add_argument("--timeout", type=float, default=900.0, help="per replay [s]")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    recording = args.recording or shared_data_dir() / DEFAULT_FLIGHT
    if not recording.exists():
        print(f"harness.bench.real_replay: skipped: {recording} not found (the shared data, UWB_HIL_DATA)",
              file=sys.stderr)
        return 0 if args.recording is None else 2
    n_bytes = link_bytes(recording)
    try:
        figs = [replay(recording, t, n_bytes, args.timeout) for t in TARGETS]
    except (RuntimeError, OSError) as e:
        print(f"harness.bench.real_replay: error: {e}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps([asdict(f) for f in figs], indent=2))
        return 0
    print(f"== real-flight replay: {recording.name} ({figs[0].flight_s:.1f} s of flight, {n_bytes / 1e6:.2f} MB "
          f"of frames, {n_bytes / figs[0].flight_s / 1e3:.0f} kB per flight second), IMU + outlier, windowed")
    print(f"{'target':7} {'wall s':>8} {'x real time':>11} {'link kB/s':>10} {'flight RMSE m':>14}")
    for f in figs:
        print(f"{f.target:7} {f.wall_s:8.2f} {f.realtime_factor:10.2f}x {f.link_bytes_per_wall_s / 1e3:10.1f} "
              f"{f.flight_rmse_m:14.3f}")
    host, qemu = figs
    print(f"QEMU / host speed: {qemu.realtime_factor / host.realtime_factor:.4f}x; goal >= 100x real time on both: "
          f"host {'met' if host.realtime_factor >= 100 else 'NOT met'}, "
          f"QEMU {'met' if qemu.realtime_factor >= 100 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
