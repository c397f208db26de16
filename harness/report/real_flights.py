"""The estimator on the real Crazyflie flights (../shared/data/cf_usd), held out by flight, through the real
command line: UWB-only against IMU-driven replays, outlier rejection with and without the real-flight network,
the tag's lever arm calibrated on training flights only, each with and without the flow deck's ToF ranger
(`--tof` / `--no-tof`), and on the evaluation flights the filter settings `uwb-hil tune` picked on the training
flights (harness/settings/cf_usd_imu_tof.toml, rows "tuned"). Every figure of docs/real-flights.md comes from here.

    python -m harness.report.real_flights [--jobs N] [--model cf_tdoa_pose.npz]      # make real-flights

Split (fixed, never tuned on): evaluation flights 0425-traj3, traj8 (TDoA2), traj13, traj18 (TDoA3), line of
sight, and the two shelf flights 0426-traj3, traj5; the lever arm of a 0425 flight is fitted on the ten other
0425 line-of-sight flights (1, 2, 4-7, 14-17: the network's training flights too), that of a shelf flight on
the other shelf flight (the vehicle was set up anew on 0426). RMSE is over the flight phase (truth above
0.4 m); the ground phase is reported apart (docs/verdicts.md). The supervisor resets are counted on all 16
shared logs in the main configurations, with and without ToF (the 0426 logs carry no ToF readings).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.biasnet.recipes import CF_USD_EVAL, CF_USD_LOS, CF_USD_SHELF, cf_usd_lever_arms
from harness.flight.formats.cf_usd_summary import usd_summary
from harness.paths import REPO_ROOT, shared_data_dir
from harness.report.replay_all import run_json

SHELF = tuple(Path(r).name for r in CF_USD_SHELF)
EVALUATION = {"0425": tuple(Path(r).name for r in CF_USD_EVAL), "0426": SHELF}   # the network's split
ALL_LOGS = tuple(Path(r).name for r in (*CF_USD_LOS, *CF_USD_SHELF))               # the 16 shared logs
#: the configurations run on every log (resets) with and without ToF: label, stages, needs the network
MAIN = (("UWB-only, outlier", ("--stages", "outlier", "--uwb-only"), False),
        ("IMU, outlier", ("--stages", "outlier"), False), ("IMU, none", ("--stages", "none"), False),
        ("IMU, outlier+nn", ("--stages", "outlier+nn"), True),
        ("IMU, outlier+nn+monitor", ("--stages", "outlier+nn+monitor"), True),
        ("IMU, outlier+nn+states", ("--stages", "outlier+nn+states"), True))
#: evaluation flights only, without ToF
EXTRA = (("IMU, outlier, UTIL lever arm", ("--stages", "outlier"), False),)
#: evaluation flights only, with ToF where the log has readings: the settings `uwb-hil tune` picked on the
#: ten 0425 training flights (harness/settings/cf_usd_imu_tof.toml)
TUNED_FILE = REPO_ROOT / "harness" / "settings" / "cf_usd_imu_tof.toml"
TUNED = tuple((f"IMU, {stages}, tuned", ("--stages", stages, "--set", f"@{TUNED_FILE}"), "nn" in stages)
              for stages in ("outlier", "outlier+nn", "outlier+nn+monitor", "outlier+nn+states"))
DEFAULT_MODEL = REPO_ROOT / "firmware_sim" / "models" / "cf_tdoa_pose.npz"


@dataclass(frozen=True)
class Job:
    flight: str
    config: str                 # label of the configuration
    args: tuple[str, ...]       # run options after --recording


@dataclass(frozen=True)
class Row:
    job: Job
    exit_code: int
    summary: dict[str, Any] | None
    reason: str

    def phase(self, name: str) -> dict[str, Any]:
        acc = (self.summary or {}).get("accuracy") or {}
        return (acc.get("phases") or {}).get(name) or {}


def log_path(data: Path, flight: str) -> Path:
    return data / "cf_usd" / flight.split("-")[0] / flight


def lever_arms(data: Path) -> dict[str, str]:
    """The `--lever-arm X,Y,Z` of each evaluation flight, fitted on flights it is not (recipes.cf_usd_lever_arms:
    the tag point the real-flight network is trained on too)."""
    return {name: ",".join(f"{v:.6f}" for v in arm) for name, arm in cf_usd_lever_arms(data).items()}


def plan(data: Path, fits: dict[str, str], model: Path | None, logs: tuple[str, ...] = ALL_LOGS) -> list[Job]:
    """Every log in the MAIN configurations, without ToF and (when it has readings) with; the evaluation flights
    also in the EXTRA ones. The lever arm is each flight's calibrated one (UTIL's for the UTIL row)."""
    evaluation = {f for flights in EVALUATION.values() for f in flights}
    jobs: list[Job] = []
    for flight in logs:
        rec = log_path(data, flight)
        if not rec.is_file():
            continue
        lever = ("--lever-arm", fits[flight]) if flight in fits else ()
        model_args = ("--model", str(model)) if model is not None else ()
        variants = (("", "--no-tof"), (", ToF", "--tof")) if usd_summary(rec).has_tof_readings else (("", "--no-tof"),)
        for label, args, nn in MAIN:
            if nn and model is None:
                continue
            jobs += [Job(flight, label + tag, (str(rec), *args, *(model_args if nn else ()), *lever, flag))
                     for tag, flag in variants]
        if flight not in evaluation:
            continue
        tag, flag = variants[-1]        # the tuned rows: with ToF where the log has readings
        for label, args, nn in (*EXTRA, *TUNED):
            if nn and model is None:
                continue
            arm = () if "UTIL" in label else lever
            tuned = label.endswith("tuned")
            jobs.append(Job(flight, label + (tag if tuned else ""),
                            (str(rec), *args, *(model_args if nn else ()), *arm, flag if tuned else "--no-tof")))
    return jobs


def run_job(job: Job, timeout_s: float = 900.0) -> Row:
    return Row(job, *run_json(job.args, timeout_s))


def _f(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None else format(x, fmt)


def markdown(rows: list[Row]) -> str:
    lines = ["| flight | configuration | flight RMSE [m] | xy | z | z mean error | attitude error (median) [deg] "
             "| ground RMSE | resets | exit |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fl, gr = r.phase("flight"), r.phase("ground")
        att = ((((r.summary or {}).get("attitude") or {}).get("phases") or {}).get("flight") or {}).get("angle_p50_deg")
        lines.append(f"| {r.job.flight} | {r.job.config} | {_f(fl.get('rmse'))} | {_f(fl.get('rmse_xy'))} | "
                     f"{_f(fl.get('rmse_z'))} | {_f(fl.get('z_mean_error'), '+.3f')} | {_f(att, '.1f')} | "
                     f"{_f(gr.get('rmse'))} | {_f(_resets(r), 'd')} | {r.exit_code} |")
    return "\n".join(lines)


def _resets(r: Row) -> int | None:
    return ((r.summary or {}).get("health") or {}).get("divergences")


def _reset_cell(r: Row | None) -> str:
    n = None if r is None else _resets(r)
    return "-" if r is None else "?" if n is None else str(n)


def resets_table(rows: list[Row]) -> str:
    """Supervisor resets per log (rows) and configuration (columns); '-' not run (no ToF readings), '?' no
    summary; the last line: total resets (logs with any)."""
    configs = list(dict.fromkeys(r.job.config for r in rows if r.job.config.split(", ToF")[0] in
                                 {label for label, _, _ in MAIN}))
    cell = {(r.job.flight, r.job.config): r for r in rows}
    flights = list(dict.fromkeys(r.job.flight for r in rows))
    lines = ["| log | " + " | ".join(configs) + " |", "|---|" + "---|" * len(configs)]
    for f in flights:
        vals = [cell.get((f, c)) for c in configs]
        lines.append(f"| {f} | " + " | ".join(_reset_cell(v) for v in vals) + " |")
    totals = []
    for c in configs:
        counts = [n for f in flights if (r := cell.get((f, c))) is not None and (n := _resets(r)) is not None]
        totals.append(f"{sum(counts)} ({sum(1 for n in counts if n)} of {len(counts)})")
    lines.append("| **total (logs with resets)** | " + " | ".join(totals) + " |")
    return "\n".join(lines)


def means(rows: list[Row], flights: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per configuration: mean flight-phase RMSE and z mean error over `flights` (runs with a summary)."""
    out: dict[str, dict[str, float]] = {}
    for config in dict.fromkeys(r.job.config for r in rows):
        sel = [r.phase("flight") for r in rows if r.job.config == config and r.job.flight in flights
               and r.phase("flight").get("rmse") is not None]
        if sel:
            out[config] = {"rmse": sum(p["rmse"] for p in sel) / len(sel),
                           "rmse_xy": sum(p.get("rmse_xy", 0.0) for p in sel) / len(sel),
                           "z_mean_error": sum(p.get("z_mean_error", 0.0) for p in sel) / len(sel), "n": len(sel)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=None,
                    help="shared recordings (default $UWB_HIL_DATA, else ../shared/data)")
    ap.add_argument("--jobs", type=int, default=2, help="runs in parallel")
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL,
                    help="the real-flight TDoA network for the outlier+nn rows (`uwb-hil models --only cfusd`)")
    args = ap.parse_args(argv)
    data = args.data_dir or shared_data_dir()
    if not (data / "cf_usd").is_dir():
        print(f"real_flights: error: no Crazyflie logs under {data / 'cf_usd'}", file=sys.stderr)
        return 2
    model = args.model if args.model.is_file() else None
    if model is None:
        print(f"real_flights: {args.model} not built (`uwb-hil models --only cfusd`): no outlier+nn rows",
              file=sys.stderr)
    fits = lever_arms(data)
    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        rows = list(pool.map(run_job, plan(data, fits, model)))
    evaluation = {f for flights in EVALUATION.values() for f in flights}
    print(markdown([r for r in rows if r.job.flight in evaluation]))
    print()
    print("supervisor resets on every shared log:")
    print(resets_table(rows))
    print()
    for label, flights in (("line of sight (0425-traj3, 8, 13, 18)", EVALUATION["0425"]), ("shelf", SHELF)):
        print(f"mean over {label}:")
        for config, m in means(rows, flights).items():
            print(f"  {config:<36} flight RMSE {m['rmse']:.3f} m, z mean error {m['z_mean_error']:+.3f} m "
                  f"xy {m['rmse_xy']:.3f} m ({m['n']} flights)")
    failed = [r for r in rows if r.summary is None]
    for r in failed:
        print(f"real_flights: {r.job.flight} / {r.job.config}: no summary (exit {r.exit_code}: {r.reason})",
              file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
