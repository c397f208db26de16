"""Radio level vs measurement level on the same flights (issue 15's acceptance figures).

    python -m harness.radio_compare              # simulated: TDoA2, TDoA3 x outlier, outlier+nn x seeds
    python -m harness.radio_compare --spread 3   # + the measurement level with its values perturbed
    python -m harness.radio_compare --util       # recorded UTIL flights: today's replay vs radio level
    python -m harness.radio_compare --noise-split  # where the white noise sits: UTIL vs the simulator

Simulated: each flight is simulated once at radio level (harness/flight/radio_sim.py); its `uwb`
stream holds the same measurements as differences (same pairs, times, link errors), so the only
difference between the two runs is the firmware's TDoA engine (the DW1000 tick, the clock correction
from noisy RX stamps, the tag's motion between the two receptions). Recorded: the recorded differences,
then the packets synthesised from them (radio_replay.py). Both run through the host firmware on a pty;
RMSE over the run's RESULTs, as `uwb-hil run` reports it.

The comparison holds only if the firmware's engine forms the measurements the twin formed for the
measurement level (harness/report/radio_streams.py checks every RESULT): a firmware built before an
engine change forms other pairs, and the levels then differ by which pairs they fly (exit 3).
--spread K flies the measurement level K more times with its values perturbed by white noise as large
as the level difference (RMS): the RMSE change such a perturbation alone causes.
--noise-split (no device): the correlation of consecutive measurements that share a tag reception, in the
recorded UTIL TDoA flights and in simulated radio-level flights (RadioConfig.tag_noise_share).
"""

from __future__ import annotations

import argparse
import glob
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from harness.config import PRESETS, EstimatorConfig
from harness.errors import report_failure
from harness.flight.data import Flight
from harness.flight.radio import radio_level
from harness.flight.scenarios import scenario_flight
from harness.report.metrics import accuracy_summary
from harness.report.radio import query_clocks, radio_summary
from harness.report.radio_streams import (FirmwareCheck, StreamComparison, compare_streams, firmware_check,
                                          shared_reception, twin_stream)
from harness.device.registry import DeviceSpec, open_device
from harness.flight.run_config import config_for
from harness.paths import shared_data_dir
from harness.stream.streamer import Pacing, Streamer


@dataclass
class Row:
    flight: str
    level: str
    stages: str
    rmse: float
    results: int
    skew_err_ppm: float | None = None
    firmware: FirmwareCheck | None = None      # radio level: the firmware formed the twin's measurements
    stream: StreamComparison | None = None     # simulated: both levels' measurement streams
    spread: tuple[float, float] | None = None  # measurement level, perturbed values: min/max RMSE change [%]


def _fly(streamer: Streamer, flight: Flight, stages: str, radio: bool, uwb_only: bool) -> Row:
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS[stages], uwb_only=uwb_only)
    run = streamer.run(flight, cfg, Pacing(mode="windowed", window=64), radio=radio)
    acc = accuracy_summary(run, flight)
    if not radio:
        return Row(flight.name, "measurement", stages, acc.rmse, run.n_received)
    skew = radio_summary(run, flight, query_clocks(streamer, flight))["max_skew_error_ppm"]
    return Row(flight.name, "radio", stages, acc.rmse, run.n_received, skew, firmware_check(run, flight))


def _spread(streamer: Streamer, flight: Flight, stages: str, rmse: float, std_m: float, k: int) -> tuple[float, float]:
    """RMSE change [%] of the measurement level with its values + white noise of std_m (k draws)."""
    changes = []
    for draw in range(k):
        rng = np.random.default_rng([draw, 15])
        u = replace(flight.uwb, value=flight.uwb.value + rng.normal(0.0, std_m, size=len(flight.uwb)))
        row = _fly(streamer, replace(flight, uwb=u), stages, False, False)
        changes.append((row.rmse - rmse) / rmse * 100.0)
    return min(changes), max(changes)


def simulated(streamer: Streamer, seeds: list[int], duration: float, spread: int = 0) -> list[tuple[Row, Row]]:
    out = []
    for protocol in ("tdoa2", "tdoa3"):
        for seed in seeds:
            base = scenario_flight("circle", mode="tdoa", duration_s=duration, seed=seed)
            flight = radio_level(base, protocol, seed=seed)
            stream = compare_streams(flight)
            for stages in ("outlier", "outlier+nn"):
                m, r = _fly(streamer, flight, stages, False, False), _fly(streamer, flight, stages, True, False)
                r.stream = stream
                if spread:
                    m.spread = _spread(streamer, flight, stages, m.rmse, stream.diff_rms_m, spread)
                out.append((m, r))
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
    spread = any(m.spread is not None for m, _ in pairs)
    print("| flight | stages | RMSE measurement level [m] | RMSE radio level [m] | change | RESULTs (meas / radio) "
          "| max clock-skew error [ppm] |" + (" perturbed measurement level: change |" if spread else ""))
    print("|---|---|---|---|---|---|---|" + ("---|" if spread else ""))
    worst = 0.0
    for m, r in pairs:
        change = (r.rmse - m.rmse) / m.rmse * 100.0
        worst = max(worst, abs(change))
        skew = "-" if r.skew_err_ppm is None else f"{r.skew_err_ppm:.4f}"
        extra = f" {m.spread[0]:+.2f} % to {m.spread[1]:+.2f} % |" if m.spread is not None else (" - |" if spread else "")
        print(f"| {m.flight} | {m.stages} | {m.rmse:.4f} | {r.rmse:.4f} | {change:+.2f} % | {m.results} / {r.results} "
              f"| {skew} |" + extra)
    print(f"\nlargest |change|: {worst:.2f} %")
    return worst


def print_streams(pairs: list[tuple[Row, Row]]) -> None:
    """One row per flight: what the two levels feed the estimator (simulated flights only)."""
    seen = set()
    if all(r.stream is None for _, r in pairs):
        return
    print("\n| flight | packets | measurements (both levels) | drops | same times and pairs | radio - measurement "
          "value: mean / RMS / max [mm] | error vs true difference, RMS meas / radio [mm] |")
    print("|---|---|---|---|---|---|---|")
    for _, r in pairs:
        s = r.stream
        if s is None or r.flight in seen:
            continue
        seen.add(r.flight)
        drops = ", ".join(f"{k} {v} ({100.0 * v / s.packets:.1f} %)" for k, v in s.drops.items()) or "none"
        print(f"| {r.flight} | {s.packets} | {s.measurements} | {drops} | {'yes' if s.same_pairs else 'NO'} "
              f"| {1e3 * s.diff_mean_m:+.2f} / {1e3 * s.diff_rms_m:.2f} / {1e3 * s.diff_max_m:.1f} "
              f"| {1e3 * s.err_rms_meas_m:.1f} / {1e3 * s.err_rms_radio_m:.1f} |")


def firmware_failures(pairs: list[tuple[Row, Row]]) -> list[str]:
    out = []
    for _, r in pairs:
        fw = r.firmware
        if fw is not None and not fw.ok:
            out.append(f"{r.flight} {r.stages}: {fw.mismatched} of {fw.checked} measurements not the twin's "
                       f"(max {fw.max_abs_m:.3g} m)")
    return out


def noise_split(data: Path, seeds: list[int], duration: float) -> int:
    """Print the shared-reception correlation of the UTIL TDoA recordings and of simulated radio-level
    flights (their twin-formed values, as a tag's engine delivers them)."""
    from harness.flight.loaders import load_recording
    print("| flight | measurement pairs sharing a tag reception | their correlation | control (no shared reception) |")
    print("|---|---|---|---|")
    paths = sorted(glob.glob(str(data / "util" / "const*" / "const*-tdoa*-extracted.csv")))
    flights = [load_recording(Path(p), anchors=data / "util" / "anchors.csv") for p in paths]
    for protocol in ("tdoa2", "tdoa3"):
        for seed in seeds:
            f = radio_level(scenario_flight("circle", mode="tdoa", duration_s=duration, seed=seed), protocol, seed=seed)
            flights.append(replace(f, uwb=replace(f.uwb, value=twin_stream(f).value)))
    for f in flights:
        s = shared_reception(f)
        print(f"| {f.name} | {s.n_shared} | {s.corr_shared:+.3f} | {s.corr_other:+.3f} |")
    return 0 if paths else 2


def usage_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the options (None: nothing): checked before any flight is simulated."""
    if args.spread < 0 or args.seeds < 1 or args.trial < 1:
        return "--spread must be >= 0, --seeds and --trial >= 1"
    if not (math.isfinite(args.duration) and args.duration > 0):
        return f"--duration must be a positive number of seconds, got {args.duration}"
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--util", action="store_true", help="recorded UTIL flights instead of simulated ones")
    ap.add_argument("--data", default=str(shared_data_dir()), help="the shared data folder (UTIL recordings)")
    ap.add_argument("--trial", type=int, default=1, help="UTIL trial number (one per constellation and protocol)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--spread", type=int, default=0, metavar="K",
                    help="simulated: also fly the measurement level K times with values perturbed by the level difference")
    ap.add_argument("--noise-split", action="store_true",
                    help="no device: where the white TDoA noise sits (UTIL recordings vs simulated radio level)")
    args = ap.parse_args(argv)
    problem = usage_problem(args)
    if problem is not None:
        print(f"radio_compare: error: {problem}", file=sys.stderr)
        return 2
    try:
        return compare(args)
    except Exception as exc:  # noqa: BLE001
        # as uwb-hil: 3 for a device or link failure, 2 for an input the harness refuses, 4 for a bug (never
        # a traceback and exit 1, which would read as "the levels differ by more than 5 %")
        return report_failure(exc, "radio_compare")


def compare(args: argparse.Namespace) -> int:
    """The comparison the options ask for: 0 within 5 %, 1 beyond, 2 no flights, 3 firmware != twin."""
    if args.noise_split:
        return noise_split(Path(args.data), list(range(1, args.seeds + 1)), args.duration)
    with open_device(DeviceSpec()) as device:
        streamer = Streamer(device, timeout_s=10.0)
        if args.util:
            pairs = recorded(streamer, Path(args.data), args.trial)
        else:
            pairs = simulated(streamer, list(range(1, args.seeds + 1)), args.duration, args.spread)
    if not pairs:
        print(f"radio_compare: error: no flights (data folder {args.data})", file=sys.stderr)
        return 2
    worst = print_table(pairs)
    print_streams(pairs)
    failures = firmware_failures(pairs)
    if failures:
        print("radio_compare: error: firmware_differs_from_twin (the levels flew different measurements; a "
              "firmware built before an engine change? `make firmware`):\n  " + "\n  ".join(failures), file=sys.stderr)
        return 3
    checked = sum(r.firmware.checked for _, r in pairs if r.firmware is not None)
    print(f"\nfirmware = twin: all {checked} radio-level measurements (value within 1 mm, same pair)")
    return 0 if worst <= 5.0 else 1


if __name__ == "__main__":
    sys.exit(main())
