"""`make bench`: a campaign on a Dask LocalCluster of 2 workers against the same campaign on 1 worker.

Both clusters run on this machine (worker processes, one thread each); the campaign is the windowed
accuracy runs of a few simulated flights (no real-time runs: their time is the flight's, whatever the
workers). Goal: 2 workers <= 0.6x the wall time of 1 worker. The machine's load average is printed with
the figure: on shared cores the ratio says as much about the neighbours as about the cluster.

    python -m harness.campaign.bench_cluster [--seeds 4] [--duration 30] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from harness.campaign.cluster import ClusterOptions, DaskExecutor
from harness.campaign.plan import CampaignOptions
from harness.campaign.runner import ExecOptions, plan_and_run

GOAL_RATIO = 0.6


def time_campaign(n_workers: int, opts: CampaignOptions) -> dict[str, Any]:
    """Wall time of the campaign on a fresh LocalCluster of `n_workers` (cluster start-up not counted)."""
    from distributed import LocalCluster
    with tempfile.TemporaryDirectory(prefix="uwb-bench-cluster-") as tmp, \
            LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address=":0", silence_logs=40) as lc:
        load = os.getloadavg()[0]
        with DaskExecutor(ClusterOptions(scheduler=lc.scheduler_address)) as ex:
            t0 = time.perf_counter()
            out = plan_and_run(Path(tmp) / "c", opts, ExecOptions(), executor=ex, log=lambda s: None)
            wall = time.perf_counter() - t0
    return {"workers": n_workers, "wall_s": wall, "runs": out.total, "ok": out.ok, "load_1min_before": load}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        import distributed  # noqa: F401
    except ImportError:
        print("bench_cluster: skipped: Dask distributed not installed (pip install 'uwb-hil[cluster]')")
        return 0
    opts = CampaignOptions(seeds=args.seeds, modes=("twr", "tdoa"), trajectories=("circle",),
                           configs=("outlier", "outlier+nn"), duration_s=args.duration, recorded=False,
                           latency_runs=False)
    one = time_campaign(1, opts)
    two = time_campaign(2, opts)
    ratio = two["wall_s"] / one["wall_s"]
    result = {"one_worker": one, "two_workers": two, "ratio": ratio, "goal": GOAL_RATIO,
              "cpu_count": os.cpu_count(), "load_average_after": [round(x, 2) for x in os.getloadavg()]}
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        print(f"Dask LocalCluster, campaign of {one['runs']} windowed runs ({args.seeds} seeds x twr,tdoa x 2 configs, "
              f"{args.duration:g} s flights), {os.cpu_count()} cores:")
        print(f"  1 worker  {one['wall_s']:6.1f} s ({one['ok']} ok, load {one['load_1min_before']:.1f} before)")
        print(f"  2 workers {two['wall_s']:6.1f} s ({two['ok']} ok, load {two['load_1min_before']:.1f} before)")
        print(f"  ratio {ratio:.2f} (goal <= {GOAL_RATIO}: {'met' if ratio <= GOAL_RATIO else 'NOT met'}; "
              f"load average now {result['load_average_after']})")
    return 0 if one["ok"] == one["runs"] and two["ok"] == two["runs"] else 1


if __name__ == "__main__":
    sys.exit(main())
