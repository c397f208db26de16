"""Campaigns on Dask distributed (`uwb-hil campaign --scheduler`, harness/campaign/cluster.py) against a real
scheduler and two worker processes on this machine: the same campaign gives the same RMSE figures as the
local process pool, the workers get the firmware by content (cached by hash) and send every file back (only
the client writes the campaign directory), and killing a worker mid-campaign loses no run: its flight is
run again elsewhere and the campaign counts the retry."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest

from harness.campaign.cluster import ClusterOptions, DaskExecutor
from harness.campaign.plan import CampaignOptions
from harness.campaign.runner import ExecOptions, plan_and_run
from harness.cli import main
from harness.errors import UsageError
from harness.paths import DEFAULT_FIRMWARE

distributed = pytest.importorskip("distributed", reason="Dask distributed not installed (the [cluster] extra)")
pytestmark = [pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)"),
              pytest.mark.timeout(300)]

SMALL = ["--seeds", "2", "--modes", "twr,tdoa", "--trajectories", "circle", "--configs", "none,outlier+nn",
         "--duration", "11", "--no-recorded", "--no-latency-runs", "--no-report"]


class _Cluster:
    """A scheduler and two single-threaded workers in their own processes, as on a real cluster. Not a
    LocalCluster: that runs the scheduler and the nannies on an IO-loop thread of the test process, whose
    logged tracebacks (CPython 3.11 parses source lines to place the carets) raced the main thread's
    `np.load` header parse and broke it (`SystemError: AST constructor recursion depth mismatch`,
    CPython gh-106905), a flake seen in fresh-clone CI."""

    def __init__(self, root: Path) -> None:
        self.cache_dir = root / "worker-cache"
        self.cache_dir.mkdir()
        self._file = root / "scheduler.json"
        self._log = (root / "cluster.log").open("w")
        env = {**os.environ, "UWB_HIL_CACHE": str(self.cache_dir)}     # the workers get the cache dir
        py = [sys.executable, "-m"]
        self._procs = [subprocess.Popen([*py, "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                         "--port", "0", "--dashboard-address", ":0",
                                         "--scheduler-file", str(self._file)],
                                        env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                        start_new_session=True)]
        self.scheduler_address = self._wait_for_file()
        self._procs.append(subprocess.Popen([*py, "distributed.cli.dask_worker", "--scheduler-file",
                                             str(self._file), "--nworkers", "2", "--nthreads", "1",
                                             "--local-directory", str(root / "workers")],
                                            env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                            start_new_session=True))
        with distributed.Client(self.scheduler_address, set_as_default=False, timeout=30) as c:
            c.wait_for_workers(2, timeout=60)

    def _wait_for_file(self) -> str:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self._file.exists():
                try:
                    return str(json.loads(self._file.read_text())["address"])
                except (ValueError, KeyError):
                    pass                     # written but not complete yet
            if self._procs[0].poll() is not None:
                break
            time.sleep(0.1)
        self.close()
        raise RuntimeError(f"the Dask scheduler did not start (log: {self._log.name})")

    def close(self) -> None:
        for p in reversed(self._procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in self._procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=20)
        self._log.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[_Cluster]:
    lc = _Cluster(tmp_path_factory.mktemp("dask"))
    try:
        yield lc
    finally:
        lc.close()


def _rmse(root: Path) -> dict[str, float]:
    from harness.report.cli import write_report
    write_report(root, as_json=False)
    rep = json.loads((root / "report.json").read_text())
    return {f"{mode}.{k}": rep[mode][k] for mode in ("twr", "tdoa") for k in ("rmse_raw", "rmse_outlier_nn")}


def test_cluster_gives_the_local_figures(cluster: _Cluster, tmp_path: Path) -> None:
    assert main(["campaign", "--out", str(tmp_path / "local"), *SMALL, "--jobs", "2"]) == 0
    assert main(["campaign", "--out", str(tmp_path / "dask"), *SMALL, "--scheduler", cluster.scheduler_address]) == 0
    local, dask = _rmse(tmp_path / "local"), _rmse(tmp_path / "dask")
    assert all(0.0 < v < 0.3 for v in local.values())
    assert dask == pytest.approx(local, rel=1e-9, abs=1e-12)
    manifest = json.loads((tmp_path / "dask" / "campaign.json").read_text())
    assert manifest["executor"]["kind"] == "dask" and manifest["executor"]["retries"] == 0
    summary = json.loads((tmp_path / "dask" / "runs" / "sim-twr-circle-s1000-none.json").read_text())
    assert summary["status"] == "ok" and summary["executor"]["worker"].startswith("tcp://127.0.0.1:")
    assert summary["spec"]["firmware"] == str(DEFAULT_FIRMWARE)     # the client's path, not the worker's cache
    cached = list(cluster.cache_dir.glob("blobs/*/uwb-fw"))         # the image travelled, by content hash
    assert len(cached) == 1 and cached[0].read_bytes() == DEFAULT_FIRMWARE.read_bytes()
    # resumed through the cluster: nothing runs again
    assert main(["campaign", "--out", str(tmp_path / "dask"), *SMALL, "--scheduler", cluster.scheduler_address]) == 0


def _kill_a_busy_worker(scheduler: str, killed: list[int]) -> None:
    """SIGKILL a worker process that is executing a flight (once)."""
    if killed:
        return
    with distributed.Client(scheduler, set_as_default=False, timeout=20) as c:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            state = c.run(lambda dask_worker: (os.getpid(), dask_worker.state.executing_count))
            busy = [pid for pid, n in state.values() if n > 0]
            if busy:
                os.kill(busy[0], signal.SIGKILL)
                killed.append(busy[0])
                return
            time.sleep(0.05)


def test_killing_a_worker_mid_campaign_loses_no_run(cluster: _Cluster, tmp_path: Path) -> None:
    opts = CampaignOptions(seeds=4, modes=("twr",), trajectories=("circle",), configs=("none", "outlier"),
                           duration_s=11.0, recorded=False, latency_runs=False)
    killed: list[int] = []
    lines: list[str] = []

    def log(line: str) -> None:
        lines.append(line)
        if line.startswith("["):       # the first flight is back: kill the worker running another one
            _kill_a_busy_worker(cluster.scheduler_address, killed)

    with DaskExecutor(ClusterOptions(scheduler=cluster.scheduler_address)) as ex:
        outcome = plan_and_run(tmp_path / "c", opts, ExecOptions(), executor=ex, log=log)
    assert killed, "no worker was busy to be killed"
    assert outcome.all_ok and outcome.ok == outcome.total == 8, lines
    assert outcome.retries >= 1, lines
    manifest = json.loads((tmp_path / "c" / "campaign.json").read_text())
    assert manifest["executor"]["retries"] == outcome.retries and manifest["executor"]["retried_flights"]
    from harness.report.cli import write_report
    write_report(tmp_path / "c", as_json=False)            # the report counts them too
    section = json.loads((tmp_path / "c" / "report.json").read_text())["sections"]["cluster"]
    assert section["retries"] == outcome.retries and sum(section["flights_per_worker"].values()) >= 4
    retried = [json.loads(p.read_text()) for p in (tmp_path / "c" / "runs").glob("*.json")]
    assert sum(1 for s in retried if s.get("executor", {}).get("retries", 0) >= 1) >= 2   # both runs of the flight


def test_unreachable_scheduler_is_an_input_error() -> None:
    with pytest.raises(UsageError, match="cannot reach the Dask scheduler"):
        with DaskExecutor(ClusterOptions(scheduler="tcp://127.0.0.1:9", connect_timeout_s=2.0)):
            pass
