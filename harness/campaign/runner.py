"""Run a planned campaign: one worker process per flight, up to `jobs` at once, each with its own host build.

Resume: runs whose summary says "ok" for the same RunSpec fingerprint are skipped, so re-running the
same command continues an interrupted campaign. A failing run (or a crashed or hung worker) is written
as "failed" with its reason and the rest go on. Workers are separate interpreters started with
subprocess: a crash in one (even a segfault) cannot take the others or the runner down.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import platform
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol

from harness.biasnet.export import DEFAULT_NPZ
from harness.campaign.models import snapshot_models
from harness.campaign.plan import (MODELS_SUMMARY, CampaignOptions, PlanError, RunSpec, attach_firmware,
                                   group_by_flight, plan_campaign, plan_digest)
from harness.campaign.shards import costliest_first, shard_runs
from harness.campaign.store import STATUS_FAILED, STATUS_OK, CampaignDir, read_json, write_json_atomic
from harness.campaign.worker import WorkerJob
from harness.options import CAMPAIGN_TIMEOUT_S
from harness.paths import REPO_ROOT
from harness.stream.streamer import Pacing


@dataclass(frozen=True)
class ExecOptions:
    jobs: int = max(1, os.cpu_count() or 1)
    window: int = Pacing.window    # measurements in flight (windowed pacing)
    timeout_s: float = CAMPAIGN_TIMEOUT_S  # device silence before a run fails
    # Wall-clock limit of one worker (a flight in every configuration); None: derived from the flight
    # length, generously (a loaded 2-core machine replays far slower than the unloaded figure).
    group_timeout_s: float | None = None
    python: str = sys.executable
    keep_jsonl: bool = False       # keep each run's JSON Lines (gzip) besides its binary rows

    def validate(self) -> None:
        if self.jobs < 1:
            raise PlanError(f"--jobs must be >= 1, got {self.jobs}")
        if not (0 < self.timeout_s <= 3600):
            raise PlanError(f"--timeout must be in (0, 3600] s, got {self.timeout_s:g}")


@dataclass
class CampaignOutcome:
    total: int
    skipped: int                                   # complete before this invocation (resumed)
    runs: list[RunSpec] = field(default_factory=list)   # this invocation's runs (a shard: its own)
    ok: int = 0
    failed: list[dict[str, Any]] = field(default_factory=list)
    retries: int = 0                               # flights run again after their worker was lost (cluster)
    boards_out: list[dict[str, Any]] = field(default_factory=list)   # boards taken out (campaign/boards.py)

    @property
    def all_ok(self) -> bool:
        return not self.failed


def host_provenance(firmware: Path | None = None) -> dict[str, Any]:
    """Where and from what the campaign ran (the device's own identity is in every run summary)."""
    def git(*args: str) -> str:
        try:
            out = subprocess.run(["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, timeout=10)
            return out.stdout.strip() if out.returncode == 0 else "unknown"
        except (OSError, subprocess.SubprocessError):
            return "unknown"

    prov: dict[str, Any] = {
        "git_commit": git("rev-parse", "HEAD"),
        "git_dirty": git("status", "--porcelain", "--untracked-files=no") not in ("", "unknown"),
        "machine": platform.node(), "platform": platform.platform(), "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        # Latency figures depend on how busy the machine was (shared cores): say so next to them.
        "load_average_1_5_15": [round(x, 2) for x in os.getloadavg()],
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if firmware is not None:
        prov["firmware_path"] = str(firmware)
        prov["firmware_sha256"] = file_sha256(Path(firmware))
    return prov


def file_sha256(path: Path) -> str:
    """First 16 hex digits of the file's SHA-256 ("missing" if it cannot be read)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    except OSError:
        return "missing"


def _group_timeout(runs: list[RunSpec], opts: ExecOptions) -> float:
    if opts.group_timeout_s is not None:
        return opts.group_timeout_s
    dur = max((r.flight.duration_s or 300.0) for r in runs)
    return 120.0 + 4.0 * dur * len(runs)


def _tail(path: Path, n: int = 20) -> str:
    try:
        return "\n".join(path.read_text(encoding="utf-8", errors="replace").splitlines()[-n:])
    except OSError:
        return ""


@dataclass
class Active:
    proc: subprocess.Popen[bytes]
    runs: list[RunSpec]
    log: Path
    deadline: float
    limit_s: float
    term_sent: float | None = None

    def why_missing(self) -> str:
        """Why a run this worker left without a summary failed."""
        if self.term_sent is not None:
            return f"worker timed out after {self.limit_s:.0f} s"
        return f"worker exited with code {self.proc.returncode} before finishing this run"


def plan_and_run(root: Path, options: CampaignOptions, exec_opts: ExecOptions, shard: tuple[int, int] | None = None,
                 log: Callable[[str], None] = print, executor: GroupExecutor | None = None) -> CampaignOutcome:
    """Plan the campaign (the options are checked before anything starts), build the firmware images the
    plan's models need (once each, cached), and run it, or shard K of N of it, into `root`."""
    exec_opts.validate()
    runs, notes = plan_campaign(options)
    runs = attach_firmware(runs)
    return run_campaign(root, runs, exec_opts, options=options, notes=notes, shard=shard, log=log, executor=executor)


class GroupExecutor(Protocol):
    """Runs flights (groups of runs) somewhere: the local process pool (default), a Dask cluster
    (campaign/cluster.py), boards (campaign/boards.py). Each group's files end up in the campaign directory
    and `ctx.group_done` is called once per group."""

    def describe(self) -> dict[str, Any]: ...

    def run(self, ctx: ExecContext, groups: list[list[RunSpec]]) -> None: ...


def run_campaign(root: Path, runs: list[RunSpec], exec_opts: ExecOptions, options: CampaignOptions | None = None,
                 notes: list[str] | None = None, log: Callable[[str], None] = print,
                 shard: tuple[int, int] | None = None, executor: GroupExecutor | None = None) -> CampaignOutcome:
    """Run `runs` (the whole plan, or with `shard` = (K, N) shard K of N of it) into `root`, on `executor`
    (default: one worker process per flight on this machine, `exec_opts.jobs` at a time)."""
    cdir = CampaignDir(Path(root).resolve())
    cdir.make()
    plan = runs
    if shard is not None:
        runs = shard_runs(plan, *shard)
    firmware = Path(plan[0].firmware) if plan else (options.firmware if options else None)
    manifest = {"options": _options_dict(options), "exec": {k: v for k, v in asdict(exec_opts).items()
                                                            if k != "python"},
                "notes": list(notes or []), "runs": [r.as_dict() for r in runs],
                "plan": {"digest": plan_digest(plan), "total": len(plan),
                         # a shard keeps the whole plan: the merged report knows which runs no shard ran
                         "runs": [r.as_dict() for r in plan] if shard is not None else None},
                "shard": {"index": shard[0], "count": shard[1]} if shard is not None else None,
                "executor": executor.describe() if executor is not None else {"kind": "local"},
                "provenance": host_provenance(firmware)}
    write_json_atomic(cdir.manifest, manifest)
    snapshot_models(cdir, [r.model for r in plan], Path(options.sim_model) if options and options.sim_model
                    else DEFAULT_NPZ, MODELS_SUMMARY, Path(options.data_dir) if options else None)
    for n in notes or []:
        log(f"note: {n}")

    fw_sha = {fw: file_sha256(Path(fw)) for fw in {r.firmware for r in runs}}
    pending_groups: list[list[RunSpec]] = []
    skipped = 0
    for group in costliest_first(group_by_flight(runs)):   # a long flight must not start last
        todo = [r for r in group if not cdir.is_complete(r.run_id, r.fingerprint(), fw_sha[r.firmware])]
        if todo != group and not cdir.flight_file_ok(group[0].flight.flight_id):
            todo = list(group)        # its stored flight is gone or damaged: fly it again (the report needs it)
        skipped += len(group) - len(todo)
        if todo:
            pending_groups.append(todo)
    outcome = CampaignOutcome(total=len(runs), skipped=skipped, runs=list(runs))
    n_pending = sum(len(g) for g in pending_groups)
    shard_text = f" (shard {shard[0]}/{shard[1]} of {len(plan)})" if shard is not None else ""
    where = f"{exec_opts.jobs} at a time" if executor is None else str(executor.describe().get("text", ""))
    log(f"campaign {cdir.root}: {len(runs)} runs{shard_text}, {skipped} already complete, {n_pending} to run "
        f"({len(pending_groups)} flights, {where})")
    ctx = ExecContext(cdir=cdir, opts=exec_opts, fw_sha=fw_sha, outcome=outcome, log=log,
                      progress=_Progress(total=len(runs), done=skipped), n_groups=len(pending_groups))
    if executor is not None:
        executor.run(ctx, pending_groups)
    else:
        _run_local(ctx, pending_groups)
    return outcome


@dataclass
class ExecContext:
    """What an executor needs to hand a finished group back: where the files go, and the tally."""

    cdir: CampaignDir
    opts: ExecOptions
    fw_sha: dict[str, str]                 # firmware path -> SHA-256 prefix (resume compares it)
    outcome: CampaignOutcome
    log: Callable[[str], None]
    progress: _Progress
    n_groups: int
    done_groups: int = 0

    def job(self, group: list[RunSpec], device: dict[str, Any] | None = None) -> WorkerJob:
        """The worker job of a group (`device`: the board it runs on; default its own host build)."""
        return WorkerJob(root=str(self.cdir.root), runs=tuple(group), window=self.opts.window,
                         timeout_s=self.opts.timeout_s, firmware_sha256=self.fw_sha[group[0].firmware],
                         keep_jsonl=self.opts.keep_jsonl, device=device)

    def annotate(self, runs: list[RunSpec], key: str, info: dict[str, Any]) -> None:
        """Add `info` under `key` to the summaries of `runs` (where they ran: a worker, a board)."""
        for run in runs:
            path = self.cdir.summary_path(run.run_id)
            try:
                summary = read_json(path)
            except (OSError, ValueError):
                continue
            summary[key] = {**summary.get(key, {}), **info}
            write_json_atomic(path, summary)

    def group_done(self, runs: list[RunSpec], why_missing: str, worker_log: Path | None, where: str = "") -> None:
        """Count the group's runs from their summaries (a run without one failed with `why_missing`), log."""
        self.done_groups += 1
        collect_runs(self.cdir, runs, self.outcome, self.log, why_missing, worker_log)
        self.log(f"[{self.progress.add(len(runs))}] {runs[0].flight.flight_id}{where} "
                 f"(flight {self.done_groups}/{self.n_groups}): {self.outcome.ok} ok, "
                 f"{len(self.outcome.failed)} failed")


def worker_env() -> dict[str, str]:
    return dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")


def _run_local(ctx: ExecContext, pending_groups: list[list[RunSpec]]) -> None:
    """One worker process per flight, up to `jobs` at once; a worker past its wall-clock limit is stopped."""
    env = worker_env()
    active: list[Active] = []
    queue = list(pending_groups)
    try:
        while queue or active:
            while queue and len(active) < max(1, ctx.opts.jobs):
                active.append(start_worker(ctx, queue.pop(0), env))
            time.sleep(0.1)
            for done in [x for x in active if worker_finished(x)]:
                active.remove(done)
                ctx.group_done(done.runs, done.why_missing(), done.log)
    finally:
        for x in active:           # interrupted: stop our workers (they stop their devices)
            if x.proc.poll() is None:
                x.proc.send_signal(signal.SIGTERM)
        for x in active:
            stop_worker(x)


def worker_finished(a: Active) -> bool:
    """Whether the worker is done; past its wall-clock limit it is stopped (SIGTERM, SIGKILL 10 s later)."""
    if a.proc.poll() is not None:
        return True
    now = time.monotonic()
    if now > a.deadline and a.term_sent is None:
        a.proc.send_signal(signal.SIGTERM)      # the worker stops its device on SIGTERM
        a.term_sent = now
    elif a.term_sent is not None and now - a.term_sent > 10.0:
        a.proc.kill()
    return False


def stop_worker(a: Active) -> None:
    """Stop a worker (SIGTERM: it stops its device), SIGKILL if it does not end within 10 s."""
    if a.proc.poll() is None:
        a.proc.send_signal(signal.SIGTERM)
    try:
        a.proc.wait(timeout=10.0)
    except subprocess.TimeoutExpired:
        a.proc.kill()
        a.proc.wait()


@dataclass
class _Progress:
    """Runs done / total and an ETA from this invocation's pace (runs resumed from disk cost nothing)."""

    total: int
    done: int
    started: float = field(default_factory=time.monotonic)
    ran: int = 0

    def add(self, n: int) -> str:
        self.done += n
        self.ran += n
        left = self.total - self.done
        elapsed = time.monotonic() - self.started
        eta = elapsed / self.ran * left if self.ran else float("nan")
        return f"{self.done}/{self.total} runs, {_clock(elapsed)} elapsed, ETA {_clock(eta) if left else '0:00'}"


def _clock(seconds: float) -> str:
    if seconds != seconds:
        return "?"
    m, s = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def _options_dict(options: CampaignOptions | None) -> dict[str, Any] | None:
    if options is None:
        return None
    d = asdict(options)
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in d.items()}


def group_stem(group: list[RunSpec]) -> str:
    """File stem of a worker's job and log. Groups are per (flight, firmware): the same flight runs on
    several firmwares (one per bias model), possibly at the same time, so the firmware is in the name;
    with the flight id alone two workers overwrote each other's job file and ran the same runs twice."""
    digest = hashlib.sha256(group[0].firmware.encode("utf-8")).hexdigest()[:8]
    return f"{group[0].flight.flight_id}.{digest}"


def start_worker(ctx: ExecContext, group: list[RunSpec], env: dict[str, str],
                 device: dict[str, Any] | None = None) -> Active:
    """A worker process for `group` (on `device`, a board, when given), its log in the campaign's logs/."""
    cdir = ctx.cdir
    for run in group:      # a summary left from an earlier attempt must not be mistaken for this one's
        cdir.summary_path(run.run_id).unlink(missing_ok=True)
    stem = group_stem(group)
    job_path = cdir.logs / f"{stem}.job.json"
    job_path.write_text(ctx.job(group, device).to_json(), encoding="utf-8")
    log_path = cdir.logs / f"{stem}.worker.log"
    with open(log_path, "wb") as fh:
        proc = subprocess.Popen([ctx.opts.python, "-m", "harness.campaign.worker", str(job_path)], cwd=REPO_ROOT,
                                stdin=subprocess.DEVNULL, stdout=fh, stderr=subprocess.STDOUT, env=env)
    limit = _group_timeout(group, ctx.opts)
    return Active(proc=proc, runs=group, log=log_path, deadline=time.monotonic() + limit, limit_s=limit)


def collect_runs(cdir: CampaignDir, runs: list[RunSpec], outcome: CampaignOutcome, log: Callable[[str], None],
                 why_missing: str, worker_log: Path | None) -> None:
    """Count a group's runs; any run left without a summary failed with its worker (`why_missing`)."""
    for run in runs:
        summary: dict[str, Any] | None = None
        if cdir.summary_path(run.run_id).exists():
            try:
                summary = read_json(cdir.summary_path(run.run_id))
            except ValueError:
                summary = None
        if summary is not None and summary.get("fingerprint") != run.fingerprint():
            summary = None
        if summary is not None and summary.get("status") == STATUS_OK:
            outcome.ok += 1
            continue
        if summary is None or summary.get("status") != STATUS_FAILED:
            summary = {"status": STATUS_FAILED, "fingerprint": run.fingerprint(), "spec": run.as_dict(),
                       "error_type": "WorkerFailed", "error": why_missing,
                       "traceback": _tail(worker_log) if worker_log else "",
                       "worker_log": str(worker_log) if worker_log else None}
            write_json_atomic(cdir.summary_path(run.run_id), summary)
        outcome.failed.append({"run_id": run.run_id, "error": summary.get("error", "")})
        first_line = str(summary.get("error", "")).splitlines()[0] if summary.get("error") else ""
        log(f"  FAILED {run.run_id}: {summary.get('error_type', '')}: {first_line}")
