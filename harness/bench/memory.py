"""Peak host memory of a long simulated flight through the host build (part of `make bench`).

Each measurement runs in a fresh subprocess (`python -m harness.bench.memory --child ...`) that builds
the flight, streams it through the host firmware on a pty and computes the run summary, then reports its
own peak RSS: the high-water mark of its own address space (`VmHWM` in /proc/self/status), which starts
afresh at exec; `resource.getrusage(RUSAGE_SELF).ru_maxrss` where there is no /proc (on Linux ru_maxrss
also counts the parent's RSS at fork, so a large parent would set a floor under every figure). The
firmware is another process and is not counted. Two paths: "sliced" (harness/flight/chunked.py + harness/stream/chunked_run.py, what
`uwb-hil run` does above 120 s) and "whole" (the flight built in one piece and streamed in one run, the
baseline measured in the same run). The goal: a 1-hour flight under 500 MB.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

GOAL_MB = 500.0


def peak_rss_mb() -> float:
    """Peak RSS of this process [MB] (module doc)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _child(duration_s: float, path: str, mode: str, firmware: str) -> dict[str, Any]:
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.scenarios import plan_scenario
    from harness.report.metrics import run_summary
    from harness.device.registry import DeviceSpec, open_device
    from harness.flight.run_config import config_for
    from harness.stream.chunked_run import stream_plan
    from harness.stream.streamer import Pacing, Streamer

    def cfg(flight: Any) -> EstimatorConfig:
        return config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])

    base_mb = peak_rss_mb()
    t0 = time.perf_counter()
    with open_device(DeviceSpec(firmware=Path(firmware), timeout_s=30.0)) as device:
        streamer = Streamer(device, timeout_s=30.0)
        plan = plan_scenario("circle", mode=mode, duration_s=duration_s, seed=1)
        if path == "sliced":
            out = stream_plan(streamer, plan, cfg, Pacing("windowed", 64))
            run, flight = out.run, out.flight
        else:
            flight = plan.whole()
            run = streamer.run(flight, cfg(flight), Pacing("windowed", 64))
        summary = run_summary(run, flight)
    return {"duration_s": duration_s, "path": path, "mode": mode, "measurements": summary["measurements"],
            "results": summary["results"], "rmse_m": summary["accuracy"]["rmse"],
            "wall_s": time.perf_counter() - t0, "imports_mb": base_mb,
            "peak_rss_mb": peak_rss_mb()}


def measure(duration_s: float, path: str, mode: str = "twr", firmware: str | None = None) -> dict[str, Any]:
    """Peak RSS of one flight in a fresh interpreter."""
    from harness.paths import DEFAULT_FIRMWARE
    cmd = [sys.executable, "-m", "harness.bench.memory", "--child", "--duration", str(duration_s), "--path", path,
           "--mode", mode, "--firmware", str(firmware or DEFAULT_FIRMWARE)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f"memory benchmark child failed ({out.returncode}): {out.stderr.strip()[-2000:]}")
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def bench_memory(durations: list[float], baseline_durations: list[float], mode: str = "twr",
                 firmware: str | None = None) -> list[dict[str, Any]]:
    rows = []
    for d in durations:
        row = measure(d, "sliced", mode, firmware)
        if d in baseline_durations:
            base = measure(d, "whole", mode, firmware)
            row["baseline_peak_rss_mb"] = base["peak_rss_mb"]
            row["baseline_wall_s"] = base["wall_s"]
            row["ratio"] = base["peak_rss_mb"] / row["peak_rss_mb"]
            row["same_rmse"] = base["rmse_m"] == row["rmse_m"]
        rows.append(row)
    return rows


def print_rows(rows: list[dict[str, Any]]) -> None:
    print(f"== peak host memory (RSS of the harness process) of a simulated flight through the host build; goal for "
          f"1 hour: < {GOAL_MB:.0f} MB")
    print(f"{'flight':>8} {'mode':5} {'measurements':>12} {'sliced MB':>10} {'whole MB':>9} {'ratio':>7} "
          f"{'sliced s':>9} {'whole s':>8} {'same RMSE':>9}")
    for r in rows:
        base = r.get("baseline_peak_rss_mb")
        print(f"{r['duration_s']:7.0f}s {r['mode']:5} {r['measurements']:12d} {r['peak_rss_mb']:10.0f} "
              f"{base if base is not None else float('nan'):9.0f} "
              f"{(str(round(r['ratio'], 1)) + 'x') if base is not None else '-':>7} {r['wall_s']:9.1f} "
              f"{r.get('baseline_wall_s', float('nan')):8.1f} {str(r.get('same_rmse', '-')):>9}")
    print(f"(interpreter + imports alone: {rows[0]['imports_mb']:.0f} MB)" if rows else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--path", choices=("sliced", "whole"), default="sliced", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, action="append", help="flight length [s] (repeatable; 600, 3600)")
    ap.add_argument("--baseline", type=float, action="append",
                    help="durations also measured whole, as the baseline (default: the same as --duration)")
    ap.add_argument("--mode", choices=("twr", "tdoa"), default="twr")
    ap.add_argument("--firmware", default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    durations = args.duration or [600.0, 3600.0]
    if args.child:
        print(json.dumps(_child(durations[0], args.path, args.mode, args.firmware)))
        return 0
    rows = bench_memory(durations, args.baseline if args.baseline is not None else durations, args.mode, args.firmware)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print_rows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
