"""The log of a device process (the host build, QEMU): where its stdout/stderr go, the temporary folder used
when no log folder is given, and the DeviceDied its exit becomes."""

from __future__ import annotations

import itertools
import os
import shutil
import tempfile
import time
from pathlib import Path

from harness.errors import DeviceDied

_counter = itertools.count()


def new_log_path(log_dir: Path | None, tmp_prefix: str, stem: str) -> tuple[Path, str | None]:
    """A fresh `<stem>-<date>-<time>-<pid>-<n>.log` in `log_dir` (created if need be) or, without one, in a new
    temporary folder; with that folder (None for log_dir), for remove_tmp_dir when the device stops."""
    tmp: str | None = None
    if log_dir is None:
        tmp = tempfile.mkdtemp(prefix=tmp_prefix)
        directory = Path(tmp)
    else:
        directory = log_dir
        directory.mkdir(parents=True, exist_ok=True)
    return directory / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}-{next(_counter)}.log", tmp


def remove_tmp_dir(tmp: str | None) -> bool:
    """Delete a temporary log folder; True if there was one (its log is gone)."""
    if tmp is None:
        return False
    shutil.rmtree(tmp, ignore_errors=True)
    return True


def exit_error(name: str, code: int, log_tail: str, log_path: Path | None, log_kept: bool) -> DeviceDied:
    """The DeviceDied of a process that exited with `code`; it names the log file when the log is kept (not in
    a temporary folder removed at stop)."""
    return DeviceDied(f"{name} exited", exit_code=code, log_tail=log_tail, log_path=log_path if log_kept else None)
