"""Campaigns on a Dask distributed cluster (`uwb-hil campaign --scheduler tcp://HOST:8786`, the [cluster] extra).

Every flight (a group of runs sharing one flight build and one device) is one task (campaign/cluster_task.py),
submitted costliest first. The firmware images and recordings it needs travel with it (content-hashed) and are
cached on each worker; results come back as bytes and only this process writes the campaign directory.
A task whose worker dies is rescheduled by the scheduler; a task that fails anyway (KilledWorker after the
scheduler's allowed failures, a lost connection) is resubmitted here up to `max_retries` times. Each
attempt is logged as a Dask event, so the campaign counts its retries (campaign.json "executor",
every run summary's "executor"). Dask is the engine: nothing here schedules.
"""

from __future__ import annotations

import os
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from harness.campaign.cluster_task import ATTEMPT_TOPIC, Blob, needed_paths, pack, run_group_task
from harness.campaign.plan import RunSpec
from harness.campaign.runner import ExecContext, group_stem
from harness.campaign.store import read_json, write_json_atomic
from harness.errors import UsageError
from harness.optional import MissingDependencyError

if TYPE_CHECKING:
    from distributed import Client, Future

SCHEDULER_ENV = "UWB_HIL_SCHEDULER"
CLUSTER_EXTRA_HINT = "pip install 'uwb-hil[cluster]' (from a checkout: pip install -e '.[cluster]'; `make` installs it)"


@dataclass(frozen=True)
class ClusterOptions:
    scheduler: str                   # tcp://HOST:8786 (or any address distributed.Client accepts)
    max_retries: int = 3             # resubmissions of a flight whose task failed (beyond Dask's own)
    connect_timeout_s: float = 30.0


def scheduler_from(arg: str | None) -> str | None:
    """--scheduler, else $UWB_HIL_SCHEDULER, else None (the local process pool)."""
    return arg or os.environ.get(SCHEDULER_ENV) or None


def _distributed() -> Any:
    try:
        import distributed
    except ImportError as exc:
        raise MissingDependencyError(f"--scheduler needs Dask distributed, which is not installed ({exc}): "
                                     f"{CLUSTER_EXTRA_HINT}") from None
    return distributed


@dataclass
class _Flight:
    group: list[RunSpec]
    stem: str
    submissions: int = 0


@dataclass
class _Tally:
    retries: int = 0
    retried: list[str] = field(default_factory=list)
    workers: dict[str, int] = field(default_factory=dict)    # flights completed per worker


class DaskExecutor:
    """A GroupExecutor (campaign/runner.py) on a Dask cluster; a context manager holding the client."""

    def __init__(self, opts: ClusterOptions) -> None:
        self.opts = opts
        self._client: Client | None = None
        self.tally = _Tally()
        self._session = uuid.uuid4().hex[:12]     # this campaign's attempts among the scheduler's events

    def __enter__(self) -> DaskExecutor:
        distributed = _distributed()
        try:
            self._client = distributed.Client(self.opts.scheduler, timeout=self.opts.connect_timeout_s,
                                              set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise UsageError(f"--scheduler {self.opts.scheduler}: cannot reach the Dask scheduler ({exc})") from None
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    @property
    def client(self) -> Client:
        if self._client is None:
            raise RuntimeError("DaskExecutor used outside its `with` block")
        return self._client

    def describe(self) -> dict[str, Any]:
        n = len(self.client.scheduler_info().get("workers", {}))
        return {"kind": "dask", "scheduler": self.opts.scheduler, "workers_at_start": n,
                "text": f"on the Dask cluster {self.opts.scheduler}, {n} workers"}

    def run(self, ctx: ExecContext, groups: list[list[RunSpec]]) -> None:
        distributed = _distributed()
        blobs = self._pack(groups)
        flights: dict[Future, _Flight] = {}
        for group in groups:          # costliest first (the runner's order): the scheduler starts them so
            fl = _Flight(group=group, stem=f"{self._session}/{group_stem(group)}")
            flights[self._submit(ctx, fl, blobs)] = fl
        done = distributed.as_completed(list(flights), loop=self.client.loop)
        try:
            for fut in done:
                fl = flights.pop(fut)
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - KilledWorker, a lost worker or connection: resubmit
                    if fl.submissions <= self.opts.max_retries:
                        ctx.log(f"  retry {fl.stem}: {type(exc).__name__}: {exc}")
                        new = self._submit(ctx, fl, blobs)
                        flights[new] = fl
                        done.add(new)
                        continue
                    self._count(fl)
                    ctx.group_done(fl.group, f"cluster task failed {fl.submissions} times: {type(exc).__name__}: "
                                             f"{exc}", None)
                    continue
                self._write(ctx, fl, result)
        finally:
            self.client.cancel(list(flights))
            self._record(ctx)

    def _pack(self, groups: list[list[RunSpec]]) -> dict[str, Blob]:
        """Every file the flights need, read once here. Each task carries its own (a firmware image is a few
        hundred kB): a scattered copy would be lost with the worker holding it, the task's never is."""
        paths = sorted({p for g in groups for r in g for p in needed_paths(r) if Path(p).exists()})
        return {p: pack(Path(p)) for p in paths}

    def _submit(self, ctx: ExecContext, fl: _Flight, blobs: dict[str, Blob]) -> Future:
        fl.submissions += 1
        for run in fl.group:     # a summary left from an earlier attempt must not be mistaken for this one's
            ctx.cdir.summary_path(run.run_id).unlink(missing_ok=True)
        need = {p: blobs[p] for r in fl.group for p in needed_paths(r) if p in blobs}
        key = f"uwb-hil-{group_stem(fl.group)}-{uuid.uuid4().hex[:8]}"
        return self.client.submit(run_group_task, ctx.job(fl.group).to_json(), fl.stem, need, key=key, pure=False)

    def _count(self, fl: _Flight) -> int:
        """Attempts of this flight beyond the first: the scheduler's reschedules (one event per attempt
        started) and this client's resubmissions, whichever saw more."""
        events = self.client.get_events(ATTEMPT_TOPIC)
        started = sum(1 for _, msg in events if isinstance(msg, dict) and msg.get("stem") == fl.stem)
        retries = max(started, fl.submissions) - 1
        if retries > 0:
            self.tally.retries += retries
            self.tally.retried.append(fl.group[0].flight.flight_id)
        return retries

    def _write(self, ctx: ExecContext, fl: _Flight, result: dict[str, Any]) -> None:
        retries = self._count(fl)
        worker = str(result.get("worker", "?"))
        self.tally.workers[worker] = self.tally.workers.get(worker, 0) + 1
        files: dict[str, bytes] = result["files"]
        # summaries last: a run is complete once its summary is there
        for rel in sorted(files, key=lambda r: (r.startswith("runs/") and r.endswith(".json"), r)):
            _write_atomic(ctx.cdir.root / rel, files[rel])
        if retries:
            ctx.annotate(fl.group, "executor", {"retries": retries})
        ctx.group_done(fl.group, "the cluster task returned no summary for this run", None,
                       where=f" on {worker}" + (f" after {retries} retries" if retries else ""))

    def _record(self, ctx: ExecContext) -> None:
        manifest = read_json(ctx.cdir.manifest)
        manifest["executor"] = {**manifest.get("executor", {}), "retries": self.tally.retries,
                                "retried_flights": self.tally.retried, "flights_per_worker": self.tally.workers}
        write_json_atomic(ctx.cdir.manifest, manifest)
        ctx.outcome.retries += self.tally.retries


def _write_atomic(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)

