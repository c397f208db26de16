"""What a Dask worker runs for one flight of a campaign (campaign/cluster.py submits it).

The worker needs nothing but the package: the firmware image and, for a recorded flight, the recording
travel with the task as `Blob`s (content and SHA-256) and are written once per worker into a cache keyed
by content hash ($UWB_HIL_CACHE, default ~/.cache/uwb-hil/blobs). The flight runs as a local campaign
worker would (`run_group`) into a scratch directory, and every file it wrote comes back to the client as
bytes: the client alone writes the campaign directory, so no shared file system is needed.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import platform
import shutil
import tarfile
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from harness.campaign.plan import RunSpec
from harness.campaign.worker import WorkerJob, run_group

CACHE_ENV = "UWB_HIL_CACHE"
#: the Dask event topic each task attempt logs (the client counts attempts per flight: the retries)
ATTEMPT_TOPIC = "uwb-hil-attempt"


@dataclass(frozen=True)
class Blob:
    """A file or directory the task needs, by content: written under <cache>/<sha256>/<name>."""

    sha256: str
    name: str
    is_dir: bool
    data: bytes            # the file, or a tar of the directory
    executable: bool = False


def pack(path: Path) -> Blob:
    """The file or directory at `path` as a Blob (a directory as a tar of its files)."""
    path = Path(path)
    if path.is_dir():
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w") as tar:
            for f in sorted(p for p in path.rglob("*") if p.is_file()):
                info = tar.gettarinfo(str(f), arcname=str(f.relative_to(path)))
                info.mtime, info.uid, info.gid, info.uname, info.gname = 0, 0, 0, "", ""
                with open(f, "rb") as fh:
                    tar.addfile(info, fh)
        data = buf.getvalue()
        return Blob(hashlib.sha256(data).hexdigest(), path.name, True, data)
    data = path.read_bytes()
    return Blob(hashlib.sha256(data).hexdigest(), path.name, False, data, os.access(path, os.X_OK))


def cache_root() -> Path:
    env = os.environ.get(CACHE_ENV)
    base = Path(env) if env else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "uwb-hil"
    return base / "blobs"


def materialize(blob: Blob, root: Path | None = None) -> Path:
    """The blob on this machine's disk, written once (content-addressed; a concurrent writer is harmless)."""
    dest_dir = (root or cache_root()) / blob.sha256
    dest = dest_dir / blob.name
    if dest.exists():
        return dest
    dest_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".part-", dir=dest_dir))
    try:
        if hashlib.sha256(blob.data).hexdigest() != blob.sha256:
            raise ValueError(f"{blob.name}: content does not match its SHA-256 {blob.sha256[:16]}")
        if blob.is_dir:
            with tarfile.open(fileobj=io.BytesIO(blob.data), mode="r") as tar:
                if hasattr(tarfile, "data_filter"):     # Python >= 3.10.12: refuse links and paths outside
                    tar.extractall(tmp / blob.name, filter="data")
                else:
                    tar.extractall(tmp / blob.name)      # noqa: S202 - our own tar, made by pack()
        else:
            (tmp / blob.name).write_bytes(blob.data)
            if blob.executable:
                (tmp / blob.name).chmod(0o755)
        try:
            os.replace(tmp / blob.name, dest)
        except OSError:          # another task of this worker wrote it first (a directory cannot be replaced)
            if not dest.exists():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def needed_paths(run: RunSpec) -> list[str]:
    """What of the client's files a run reads: its firmware, and a recorded flight's recording and anchors."""
    out = [run.firmware]
    out += [p for p in (run.flight.path, run.flight.anchors) if p]
    return out


def localize(run: RunSpec, where: dict[str, str]) -> RunSpec:
    """The run with the client's paths replaced by this worker's copies."""
    flight = replace(run.flight, path=where.get(run.flight.path or "", run.flight.path),
                     anchors=where.get(run.flight.anchors or "", run.flight.anchors))
    return replace(run, firmware=where.get(run.firmware, run.firmware), flight=flight)


def _restore_summary(text: bytes, run: RunSpec, worker: dict[str, Any]) -> bytes:
    """The summary as the client planned the run (its fingerprint and spec name the client's paths; the
    content is the same by hash), with where it ran."""
    summary = json.loads(text)
    summary["fingerprint"] = run.fingerprint()
    summary["spec"] = run.as_dict()
    if isinstance(summary.get("flight"), dict) and "path" in summary["flight"]:
        summary["flight"]["path"] = run.flight.path
    summary["executor"] = worker
    return json.dumps(summary, indent=1).encode("utf-8")


def _worker_address() -> str:
    try:
        from distributed import get_worker
        return str(get_worker().address)
    except (ImportError, ValueError):
        return "local"


def _log_attempt(stem: str) -> None:
    try:
        from distributed import get_worker
        get_worker().log_event(ATTEMPT_TOPIC, {"stem": stem})
    except (ImportError, ValueError):
        pass


def run_group_task(job_json: str, stem: str, blobs: dict[str, Blob]) -> dict[str, Any]:
    """Run one flight's runs on this worker; {"files": {relative path: bytes}, "worker": address}."""
    _log_attempt(stem)
    job = WorkerJob.from_json(job_json)
    where = {orig: str(materialize(blob)) for orig, blob in blobs.items()}
    worker = {"kind": "dask", "worker": _worker_address(), "host": platform.node()}
    with tempfile.TemporaryDirectory(prefix="uwb-hil-task-") as scratch:
        local = replace(job, root=scratch, runs=tuple(localize(r, where) for r in job.runs))
        run_group(local)
        files: dict[str, bytes] = {}
        by_id = {r.run_id: r for r in job.runs}
        for f in sorted(p for p in Path(scratch).rglob("*") if p.is_file()):
            rel = str(f.relative_to(scratch))
            data = f.read_bytes()
            if rel.startswith("runs/") and f.suffix == ".json" and f.stem in by_id:
                data = _restore_summary(data, by_id[f.stem], worker)
            files[rel] = data
    return {"files": files, "worker": worker["worker"]}
