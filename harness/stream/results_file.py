"""Results files (JSON Lines) are opened safely: one writer at a time, no silent loss of an unfinished run.

* Every writer holds an exclusive `fcntl.flock` on the file for as long as it writes: a second run (or a
  resume) on the same file fails at once with a clear error instead of interleaving lines.
* A new run refuses a file that holds an unfinished (resumable) run, or that is not a results file at
  all, unless `overwrite`; it then truncates the file only once it holds the lock.
* Write errors (disk full, /dev/full, a directory) are `ResultsFileError`s naming the file.
* `flight_digest` fingerprints the flight a file was recorded from, so a resume can tell an edited
  recording or another flight from the one recorded.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
from pathlib import Path
from typing import IO, Any

import numpy as np

from harness.errors import ResultsFileError
from harness.flight.data import Flight


def _oserror(path: Path, what: str, exc: OSError) -> ResultsFileError:
    reason = exc.strerror or str(exc)
    if exc.errno == errno.EISDIR or (exc.errno in (errno.ENOTDIR, None) and path.is_dir()):
        return ResultsFileError(f"results file {path} is a directory: give a file name, e.g. {path / 'run.jsonl'}")
    return ResultsFileError(f"cannot {what} results file {path}: {reason}")


def lock_file(path: Path, mode: str) -> IO[str]:
    """Open `path` ('a+' creates it, 'r+' needs it) and take an exclusive lock without waiting."""
    path = Path(path)
    if path.is_dir():
        raise ResultsFileError(f"results file {path} is a directory: give a file name, e.g. {path / 'run.jsonl'}")
    try:
        if mode == "a+":
            path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path, mode, encoding="utf-8")
    except OSError as exc:
        raise _oserror(path, "open", exc) from None
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.close()
        raise ResultsFileError(f"results file {path} is in use by another uwb-hil run (it holds the file's lock); "
                               "wait for it to finish or use another file") from None
    except OSError as exc:     # a file system without locks: say so rather than write unprotected
        fh.close()
        raise _oserror(path, "lock", exc) from None
    return fh


def check_not_in_use(path: Path) -> None:
    """Fail now, before any device starts, if another run holds the file's lock (then released at once)."""
    if Path(path).is_file():
        lock_file(Path(path), "r+").close()


def describe_existing(path: Path) -> str | None:
    """Why `path` must not be overwritten silently (None if it may): an unfinished run, or not a results file.
    A complete run (every measurement has a line) may be replaced: it is finished, nothing is lost that a
    re-run would not write again."""
    try:
        if not path.is_file() or path.stat().st_size == 0:
            return None
        with open(path, encoding="utf-8", errors="replace") as fh:
            first = fh.readline()
            try:
                header = json.loads(first)
            except json.JSONDecodeError:
                header = None
            if not isinstance(header, dict) or header.get("type") != "header" or "n_measurements" not in header:
                return "it is not a uwb-hil results file (its first line is not a run header)"
            n = sum(1 for line in fh if line.startswith('{"type": "result"') and line.endswith("}\n"))
    except OSError:
        return None
    total = int(header["n_measurements"]) if isinstance(header["n_measurements"], int) else -1
    if n < total:
        return (f"it holds an unfinished run of {header.get('flight')!r} ({n} of {total} results): continue it with "
                f"`uwb-hil run --resume {path}`")
    return None


class LockedResults:
    """A results file opened for a new run: locked, checked, truncated. `fh` is written by ResultsWriter."""

    def __init__(self, path: Path, overwrite: bool = True) -> None:
        self.path = Path(path)
        self.fh = lock_file(self.path, "a+")
        try:
            why = describe_existing(self.path)
            if why is not None and not overwrite:
                raise ResultsFileError(f"results file {self.path} not overwritten: {why}, or pass --overwrite")
            if self.path.is_file():
                self.fh.seek(0)
                self.fh.truncate(0)
        except BaseException:
            self.fh.close()
            raise

    @classmethod
    def existing(cls, path: Path) -> "LockedResults":
        """An existing results file, locked for a resume (read, then appended to; never truncated here)."""
        self = cls.__new__(cls)
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"results file {self.path} not found")
        self.fh = lock_file(self.path, "r+")
        return self

    def write(self, text: str) -> None:
        try:
            self.fh.write(text)
            self.fh.flush()
        except OSError as exc:
            raise _oserror(self.path, "write", exc) from None

    def close(self) -> None:
        if self.fh.closed:
            return
        try:
            self.fh.close()          # closing releases the lock
        except OSError as exc:       # the final flush failed (disk full)
            raise _oserror(self.path, "write", exc) from None


def truncate_partial_line(fh: IO[str], path: Path) -> int:
    """Cut a partial last line (a run killed mid-write) so appended records start on a line of their own.
    Returns the number of bytes removed."""
    fh.flush()
    size = os.fstat(fh.fileno()).st_size
    with open(path, "rb") as raw:
        data = raw.read()
    keep = data.rfind(b"\n") + 1
    if keep == len(data):
        return 0
    fh.truncate(keep)
    fh.seek(keep)
    return size - keep


def flight_digest(flight: Flight) -> str:
    """SHA-256 (16 hex digits) of what is streamed: measurements, IMU, anchors, and the truth scored against."""
    digest = FlightDigest()
    digest.update(flight, last=True)
    return digest.hexdigest()


class FlightDigest:
    """`flight_digest` fed slice by slice (harness/flight/chunked.py: consecutive slices share one truth
    sample, counted once): one hash per array, combined at the end, so a 1-hour flight built in slices
    gets the digest of the same flight built whole."""

    _NAMES = ("kind", "uwb_t", "anchor_a", "anchor_b", "value", "anchor_ids", "anchor_pos", "truth_t", "truth_pos",
              "imu_t", "imu_acc", "imu_gyro")

    def __init__(self) -> None:
        self._h = {n: hashlib.sha256() for n in self._NAMES}
        self._meta: dict[str, tuple[str, int]] = {}
        self._fixed_done = False

    def _add(self, name: str, arr: Any) -> None:
        a = np.ascontiguousarray(arr)
        dtype, rows = self._meta.get(name, (str(a.dtype), 0))
        self._meta[name] = (dtype, rows + (a.shape[0] if a.ndim else 1))
        self._h[name].update(a.tobytes())

    def update(self, piece: Flight, last: bool) -> None:
        u = piece.uwb
        if not self._fixed_done:
            self._add("kind", np.int64(u.kind))
            self._add("anchor_ids", piece.anchors.ids)
            self._add("anchor_pos", piece.anchors.positions)
            self._fixed_done = True
        for name, arr in (("uwb_t", u.t_us), ("anchor_a", u.anchor_a), ("anchor_b", u.anchor_b), ("value", u.value)):
            self._add(name, arr)
        keep = slice(None) if last else slice(0, max(0, len(piece.truth.t_us) - 1))
        self._add("truth_t", piece.truth.t_us[keep])
        self._add("truth_pos", piece.truth.pos[keep])
        if piece.imu is not None:
            for name, arr in (("imu_t", piece.imu.t_us), ("imu_acc", piece.imu.acc), ("imu_gyro", piece.imu.gyro)):
                self._add(name, arr)

    def hexdigest(self) -> str:
        h = hashlib.sha256()
        for name in self._NAMES:
            if name in self._meta:
                dtype, rows = self._meta[name]
                h.update(f"{name}:{dtype}:{rows}:".encode() + self._h[name].digest())
        return h.hexdigest()[:16]
