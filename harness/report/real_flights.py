"""The estimator on the real Crazyflie flights (../shared/data/cf_usd), held out by flight, through the real
command line: UWB-only against IMU-driven replays, outlier rejection with and without the real-flight network,
the tag's lever arm calibrated on training flights only. Every figure of docs/real-flights.md comes from here.

    python -m harness.report.real_flights [--jobs N] [--model cf_tdoa_pose.npz]      # make real-flights

Split (fixed, never tuned on): evaluation flights 0425-traj3, traj8 (TDoA2), traj13, traj18 (TDoA3), line of
sight, and the two shelf flights 0426-traj3, traj5; the lever arm of a 0425 flight is fitted on the ten other
0425 line-of-sight flights (1, 2, 4-7, 14-17: the network's training flights too), that of a shelf flight on
the other shelf flight (the vehicle was set up anew on 0426). RMSE is over the flight phase (truth above
0.4 m); the ground phase is reported apart (docs/verdicts.md).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from harness.biasnet.recipes import CF_USD_EVAL, CF_USD_SHELF, cf_usd_lever_arms
from harness.paths import REPO_ROOT, shared_data_dir
from harness.report.replay_all import run_json

SHELF = tuple(Path(r).name for r in CF_USD_SHELF)
EVALUATION = {"0425": tuple(Path(r).name for r in CF_USD_EVAL), "0426": SHELF}   # the network's split
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


def plan(data: Path, fits: dict[str, str], model: Path | None) -> list[Job]:
    jobs: list[Job] = []
    for flights in EVALUATION.values():
        for flight in flights:
            rec = str(log_path(data, flight))
            lever = ("--lever-arm", fits[flight])
            jobs += [Job(flight, "UWB-only, outlier", (rec, "--stages", "outlier", "--uwb-only", *lever)),
                     Job(flight, "IMU, outlier, UTIL lever arm", (rec, "--stages", "outlier")),
                     Job(flight, "IMU, outlier", (rec, "--stages", "outlier", *lever)),
                     Job(flight, "IMU, none", (rec, "--stages", "none", *lever))]
            if model is not None:
                jobs += [Job(flight, f"IMU, {stages}", (rec, "--stages", stages, "--model", str(model), *lever))
                         for stages in ("outlier+nn", "outlier+nn+monitor", "outlier+nn+states")]
    return jobs


def run_job(job: Job, timeout_s: float = 900.0) -> Row:
    return Row(job, *run_json(job.args, timeout_s))


def _f(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None else format(x, fmt)


def markdown(rows: list[Row]) -> str:
    lines = ["| flight | configuration | flight RMSE [m] | xy | z mean error | attitude error (median) [deg] | "
             "ground RMSE | resets | exit |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fl, gr = r.phase("flight"), r.phase("ground")
        att = ((((r.summary or {}).get("attitude") or {}).get("phases") or {}).get("flight") or {}).get("angle_p50_deg")
        resets = ((r.summary or {}).get("health") or {}).get("divergences")
        lines.append(f"| {r.job.flight} | {r.job.config} | {_f(fl.get('rmse'))} | {_f(fl.get('rmse_xy'))} | "
                     f"{_f(fl.get('z_mean_error'), '+.3f')} | {_f(att, '.1f')} | {_f(gr.get('rmse'))} | "
                     f"{_f(resets, 'd')} | {r.exit_code} |")
    return "\n".join(lines)


def means(rows: list[Row], flights: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """Per configuration: mean flight-phase RMSE and z mean error over `flights` (runs with a summary)."""
    out: dict[str, dict[str, float]] = {}
    for config in dict.fromkeys(r.job.config for r in rows):
        sel = [r.phase("flight") for r in rows if r.job.config == config and r.job.flight in flights
               and r.phase("flight").get("rmse") is not None]
        if sel:
            out[config] = {"rmse": sum(p["rmse"] for p in sel) / len(sel),
                           "z_mean_error": sum(p.get("z_mean_error", 0.0) for p in sel) / len(sel), "n": len(sel)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=None, help="shared recordings (default ../shared/data)")
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
    print(markdown(rows))
    print()
    for label, flights in (("line of sight (0425-traj3, 8, 13, 18)", EVALUATION["0425"]), ("shelf", SHELF)):
        print(f"mean over {label}:")
        for config, m in means(rows, flights).items():
            print(f"  {config:<30} flight RMSE {m['rmse']:.3f} m, z mean error {m['z_mean_error']:+.3f} m "
                  f"({m['n']} flights)")
    failed = [r for r in rows if r.summary is None]
    for r in failed:
        print(f"real_flights: {r.job.flight} / {r.job.config}: no summary (exit {r.exit_code}: {r.reason})",
              file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
