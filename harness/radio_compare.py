"""Radio level vs measurement level on the same flights (issue 15's acceptance figures).

    python -m harness.radio_compare              # simulated: TDoA2, TDoA3 x outlier, outlier+nn x seeds
    python -m harness.radio_compare --util       # recorded UTIL flights: today's replay vs radio level

Simulated: each flight is simulated once at radio level (harness/flight/radio_sim.py); its `uwb`
stream holds the same measurements as differences (same pairs, times, link errors), so the only
difference between the two runs is the firmware's TDoA engine (and the DW1000 tick quantisation).
Recorded: the recorded differences, then the packets synthesised from them (radio_replay.py).
Both run through the host firmware on a pty; RMSE over the run's RESULTs, as `uwb-hil run` reports it.
"""

from __future__ import annotations

import argparse
import glob
import sys
from dataclasses import dataclass
from pathlib import Path

from harness.config import PRESETS, EstimatorConfig
from harness.flight.data import Flight
from harness.flight.radio import radio_level
from harness.flight.scenarios import scenario_flight
from harness.report.metrics import accuracy_summary
from harness.report.radio import query_clocks, radio_summary
from harness.session import DeviceSpec, config_for, open_device, shared_data_dir
from harness.stream.streamer import Pacing, Streamer


@dataclass
class Row:
    flight: str
    level: str
    stages: str
    rmse: float
    results: int
    skew_err_ppm: float | None = None


def _fly(streamer: Streamer, flight: Flight, stages: str, radio: bool, uwb_only: bool) -> Row:
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS[stages], uwb_only=uwb_only)
    run = streamer.run(flight, cfg, Pacing(mode="windowed", window=64), radio=radio)
    acc = accuracy_summary(run, flight)
    skew = radio_summary(run, flight, query_clocks(streamer, flight))["max_skew_error_ppm"] if radio else None
    return Row(flight.name, "radio" if radio else "measurement", stages, acc.rmse, run.n_received, skew)


def simulated(streamer: Streamer, seeds: list[int], duration: float) -> list[tuple[Row, Row]]:
    out = []
    for protocol in ("tdoa2", "tdoa3"):
        for seed in seeds:
            base = scenario_flight("circle", mode="tdoa", duration_s=duration, seed=seed)
            flight = radio_level(base, protocol, seed=seed)
            for stages in ("outlier", "outlier+nn"):
                out.append((_fly(streamer, flight, stages, False, False), _fly(streamer, flight, stages, True, False)))
    return out


def recorded(streamer: Streamer, data: Path, trial: int) -> list[tuple[Row, Row]]:
    from harness.flight.loaders import load_recording
    out = []
    for path in sorted(glob.glob(str(data / "util" / "const*" / f"const*-trial{trial}-tdoa*-extracted.csv"))):
        flight = load_recording(Path(path), anchors=data / "util" / "anchors.csv")
        protocol = "tdoa3" if "tdoa3" in Path(path).name else "tdoa2"
        rflight = radio_level(flight, protocol)
        out.append((_fly(streamer, flight, "outlier", False, True), _fly(streamer, rflight, "outlier", True, True)))
    return out


def print_table(pairs: list[tuple[Row, Row]]) -> float:
    print("| flight | stages | RMSE measurement level [m] | RMSE radio level [m] | change | RESULTs (meas / radio) "
          "| max clock-skew error [ppm] |")
    print("|---|---|---|---|---|---|---|")
    worst = 0.0
    for m, r in pairs:
        change = (r.rmse - m.rmse) / m.rmse * 100.0
        worst = max(worst, abs(change))
        skew = "-" if r.skew_err_ppm is None else f"{r.skew_err_ppm:.4f}"
        print(f"| {m.flight} | {m.stages} | {m.rmse:.4f} | {r.rmse:.4f} | {change:+.2f} % | {m.results} / {r.results} "
              f"| {skew} |")
    print(f"\nlargest |change|: {worst:.2f} %")
    return worst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--util", action="store_true", help="recorded UTIL flights instead of simulated ones")
    ap.add_argument("--data", default=str(shared_data_dir()), help="the shared data folder (UTIL recordings)")
    ap.add_argument("--trial", type=int, default=1, help="UTIL trial number (one per constellation and protocol)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    args = ap.parse_args(argv)
    with open_device(DeviceSpec()) as device:
        streamer = Streamer(device, timeout_s=10.0)  # type: ignore[arg-type]
        if args.util:
            pairs = recorded(streamer, Path(args.data), args.trial)
        else:
            pairs = simulated(streamer, list(range(1, args.seeds + 1)), args.duration)
    if not pairs:
        print(f"radio_compare: error: no flights (data folder {args.data})", file=sys.stderr)
        return 2
    worst = print_table(pairs)
    return 0 if worst <= 5.0 else 1


if __name__ == "__main__":
    sys.exit(main())
