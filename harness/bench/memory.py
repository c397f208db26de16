"""Peak host memory of a long simulated flight through the host build (part of `make bench`).

Each measurement runs in a fresh subprocess (`python -m harness.bench.memory --child ...`) that builds
the flight, streams it through the host firmware on a pty and computes the run summary, then reports its
own peak RSS: the high-water mark of its own address space (`VmHWM` in /proc/self/status), which starts
afresh at exec; `resource.getrusage(RUSAGE_SELF).ru_maxrss` where there is no /proc (on Linux ru_maxrss
also counts the parent's RSS at fork, so a large parent would set a floor under every figure). The
firmware is another process and is not counted. Two paths: "sliced" (harness/flight/chunked.py + harness/stream/chunked_run.py, what
`uwb-hil run` does above 120 s) and "whole" (the flight built in one piece and streamed in one run, the
baseline measured in the same run). The goal: a 1-hour flight under 500 MB. A third figure: resuming the
second half of the same flight from a results file cut half-way (`uwb-hil run --resume`, which replays and
streams it in slices too): at most 1.5x the sliced run's peak.
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
#: resuming half of a flight may take at most this times the plain (sliced) run's peak RSS
RESUME_GOAL = 1.5


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


def _child_resume(results: str, firmware: str) -> dict[str, Any]:
    """Resume the half-run in `results` (as `uwb-hil run --resume` does) and report the peak RSS."""
    from harness.device.registry import DeviceSpec
    from harness.run.single import resume_one
    base_mb = peak_rss_mb()
    t0 = time.perf_counter()
    summary = resume_one(Path(results), lambda src: (DeviceSpec(firmware=Path(firmware), timeout_s=30.0), None), 30.0)
    return {"path": "resume", "measurements": summary["measurements"], "results": summary["results"],
            "rmse_m": summary["accuracy"]["rmse"], "resumed_at": summary["resume"]["resumed_at"],
            "wall_s": time.perf_counter() - t0, "imports_mb": base_mb, "peak_rss_mb": peak_rss_mb()}


def half_run(duration_s: float, mode: str, firmware: str, work: Path) -> Path:
    """A results file of the flight with its second half cut off (as if the run was killed half-way): the
    whole run written by `uwb-hil run --results`, then copied line by line up to half its results."""
    full, half = work / "full.jsonl", work / "half.jsonl"
    cmd = [sys.executable, "-m", "harness.cli", "run", "--scenario", "circle", "--mode", mode, "--duration",
           str(duration_s), "--seed", "1", "--stages", "outlier+nn", "--results", str(full), "--firmware", firmware,
           "--timeout", "30", "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=7200)
    if out.returncode not in (0, 1):
        raise RuntimeError(f"the run to resume failed ({out.returncode}): {out.stderr.strip()[-2000:]}")
    n = int(json.loads(out.stdout)["measurements"])
    kept = 0
    with open(full, encoding="utf-8") as src, open(half, "w", encoding="utf-8") as dst:
        for line in src:
            if line.startswith('{"type": "result"'):
                if kept >= n // 2:
                    break
                kept += 1
            dst.write(line)
    full.unlink()
    return half


def measure(duration_s: float, path: str, mode: str = "twr", firmware: str | None = None) -> dict[str, Any]:
    """Peak RSS of one flight in a fresh interpreter ("resume": of resuming its second half)."""
    from harness.paths import DEFAULT_FIRMWARE
    fw = str(firmware or DEFAULT_FIRMWARE)
    if path == "resume":
        import tempfile
        with tempfile.TemporaryDirectory(prefix="uwb-hil-bench-resume-") as work:
            results = half_run(duration_s, mode, fw, Path(work))
            return _run_child(["--path", "resume", "--results", str(results), "--firmware", fw])
    return _run_child(["--duration", str(duration_s), "--path", path, "--mode", mode, "--firmware", fw])


def _run_child(args: list[str]) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "harness.bench.memory", "--child", *args]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f"memory benchmark child failed ({out.returncode}): {out.stderr.strip()[-2000:]}")
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def bench_memory(durations: list[float], baseline_durations: list[float], mode: str = "twr",
                 firmware: str | None = None) -> list[dict[str, Any]]:
    rows = []
    for d in durations:
        row = measure(d, "sliced", mode, firmware)
        resumed = measure(d, "resume", mode, firmware)
        row["resume_peak_rss_mb"] = resumed["peak_rss_mb"]
        row["resume_ratio"] = resumed["peak_rss_mb"] / row["peak_rss_mb"]
        row["resume_same_rmse"] = abs(resumed["rmse_m"] - row["rmse_m"]) <= 1e-9 * max(1.0, row["rmse_m"])
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
          f"{'sliced s':>9} {'whole s':>8} {'same RMSE':>9} {'resume MB':>10} {'resume/sliced':>13} {'same':>5}")
    for r in rows:
        base = r.get("baseline_peak_rss_mb")
        print(f"{r['duration_s']:7.0f}s {r['mode']:5} {r['measurements']:12d} {r['peak_rss_mb']:10.0f} "
              f"{base if base is not None else float('nan'):9.0f} "
              f"{(str(round(r['ratio'], 1)) + 'x') if base is not None else '-':>7} {r['wall_s']:9.1f} "
              f"{r.get('baseline_wall_s', float('nan')):8.1f} {str(r.get('same_rmse', '-')):>9} "
              f"{r['resume_peak_rss_mb']:10.0f} {r['resume_ratio']:12.2f}x {str(r['resume_same_rmse']):>5}")
    print(f"(resume: the second half of the same flight resumed from a results file cut half-way, "
          f"`uwb-hil run --resume`; goal: at most {RESUME_GOAL:g}x the sliced run)")
    print(f"(interpreter + imports alone: {rows[0]['imports_mb']:.0f} MB)" if rows else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--path", choices=("sliced", "whole", "resume"), default="sliced", help=argparse.SUPPRESS)
    ap.add_argument("--results", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, action="append", help="flight length [s] (repeatable; 600, 3600)")
    ap.add_argument("--baseline", type=float, action="append",
                    help="durations also measured whole, as the baseline (default: the same as --duration)")
    ap.add_argument("--mode", choices=("twr", "tdoa"), default="twr")
    ap.add_argument("--firmware", default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    durations = args.duration or [600.0, 3600.0]
    if args.child:
        fw = args.firmware
        result = _child_resume(args.results, fw) if args.path == "resume" else _child(durations[0], args.path,
                                                                                        args.mode, fw)
        print(json.dumps(result))
        return 0
    rows = bench_memory(durations, args.baseline if args.baseline is not None else durations, args.mode, args.firmware)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print_rows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
