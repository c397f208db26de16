"""The results file: the one owner of its format, and its safe opening.

Format (JSON Lines; a campaign also keeps the rows as a binary .npy of RESULTS_DTYPE):

    {"type": "header", "flight", "config", "pacing", "n_measurements", ...}   line 1: the run
    {"type": "result", "index": k, <RESULT fields>, "t_send_ns", "t_recv_ns", "outcome", "error_code"}
    {"type": "device_error", <ERROR fields>}      an ERROR about no pending measurement
    {"type": "resume", ...}                       a resume appended the lines after it
    {"type": "stats", <STATS fields>, "host_decoder": {...}}   the device counters at the end of the run

The RESULT fields are those of the protocol's RESULT message (protocol/messages.toml), in its order and
with its dtypes; the host adds when the measurement was sent and answered, its outcome and an error code.
`ResultsWriter` writes, `read_run` reads (the resume and the campaign report both read through it).

Opening: every writer holds an exclusive `fcntl.flock` on the file for as long as it writes (a second run
or a resume on the same file fails at once); a new run refuses a file that holds an unfinished run, or
that is not a results file, unless `overwrite`; write errors are `ResultsFileError`s naming the file.
"""

from __future__ import annotations

import errno
import fcntl
import gzip
import json
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterable, Iterator

import numpy as np

from harness.errors import InputFileNotFound, ResultsFileError
from protocol import messages as m
from protocol.batch import RESULT_DTYPE

# ------------------------------------------------------------------------------------------ the format
#: the outcome of a measurement (column "outcome")
OUTCOME_PENDING, OUTCOME_RESULT, OUTCOME_ERROR, OUTCOME_LOST = 0, 1, 2, 3
#: a RADIO packet the device used but that formed no measurement (RADIO_DROP; error_code = drop_reason)
OUTCOME_NO_MEAS = 4

#: the record types (field "type")
REC_HEADER, REC_RESULT, REC_STATS, REC_RESUME, REC_DEVICE_ERROR = "header", "result", "stats", "resume", "device_error"

#: the RESULT message's fields (protocol), then the host's columns
RESULT_FIELDS: tuple[str, ...] = tuple(name for name, _ in m.Result.FIELDS)
HOST_COLUMNS = (("t_send_ns", "<i8"), ("t_recv_ns", "<i8"), ("outcome", "i1"), ("error_code", "u1"))
RESULTS_DTYPE = np.dtype([(name, RESULT_DTYPE[name]) for name in RESULT_FIELDS] + list(HOST_COLUMNS))
#: the RESULT fields are one packed run of bytes in the decoder's RESULT_DTYPE and in RESULTS_DTYPE
RESULT_BYTES_OFFSET = RESULT_DTYPE.fields[RESULT_FIELDS[0]][1]
RESULT_BYTES = sum(RESULTS_DTYPE[name].itemsize for name in RESULT_FIELDS)
assert all(RESULTS_DTYPE.fields[n][1] + RESULT_BYTES_OFFSET == RESULT_DTYPE.fields[n][1] for n in RESULT_FIELDS)
#: every column of a result line: its index in the flight, then RESULTS_DTYPE's
COLUMNS: tuple[str, ...] = ("index", *(RESULTS_DTYPE.names or ()))


def is_integer(column: str) -> bool:
    """An integer column (index, counters, times in us/ns, status, outcome) rather than a float."""
    return column == "index" or RESULTS_DTYPE[column].kind in "iu"


def column_dtype(column: str) -> type:
    """The dtype a reader gives a column: int64 or float64."""
    return np.int64 if is_integer(column) else np.float64


def header_record(header: dict[str, Any]) -> dict[str, Any]:
    return {"type": REC_HEADER, **header}


def result_lines(idx: Iterable[int], rows: np.ndarray) -> str:
    """Result lines for rows of RESULTS_DTYPE at flight indices idx (newline-terminated)."""
    names = RESULTS_DTYPE.names or ()
    out = []
    for k, row in zip(list(idx), rows.tolist()):
        rec = {"type": REC_RESULT, "index": int(k)}
        rec.update(zip(names, row))
        out.append(json.dumps(rec) + "\n")
    return "".join(out)


class ResultsWriter:
    """JSON Lines on disk, appended and flushed as results arrive (an interrupted run keeps them; a killed
    harness loses at most the line being written). The file is locked while written; `overwrite=False`
    refuses a file holding an unfinished run. `path=None` writes nothing. `offset` is added to the indices
    (a resume, or the slices of a long flight, write rows of the whole flight)."""

    def __init__(self, path: Path | None, header: dict[str, Any] | None, overwrite: bool = True,
                 locked: "LockedResults | None" = None, offset: int = 0) -> None:
        self._fh: LockedResults | None = locked
        self.offset = offset
        if path is not None:
            self._fh = LockedResults(Path(path), overwrite=overwrite)
        if self._fh is not None and header is not None:
            self._write(json.dumps(header_record(header)) + "\n")

    def _write(self, text: str) -> None:
        assert self._fh is not None
        try:
            self._fh.write(text)
        except BaseException:
            fh, self._fh = self._fh, None
            try:
                fh.fh.close()        # releases the lock; the unwritten buffer is lost with the error raised
            except OSError:
                pass
            raise

    def write_rows(self, idx: np.ndarray, rows: np.ndarray) -> None:
        if self._fh is not None and len(idx):
            self._write(result_lines(np.asarray(idx) + self.offset, rows))

    def write_record(self, record: dict[str, Any]) -> None:
        if self._fh is not None:
            self._write(json.dumps(record) + "\n")

    def close(self) -> None:
        if self._fh is not None:
            fh, self._fh = self._fh, None
            fh.close()


@dataclass
class RunRecords:
    """A results file as read: the header, every result column in flight order, the other records."""
    path: Path
    header: dict[str, Any]
    columns: dict[str, np.ndarray]          # column -> (M,) array (column_dtype), row k = measurement k
    stats: dict[str, Any] | None = None     # the last "stats" record
    records: list[dict[str, Any]] = field(default_factory=list)   # device_error, resume, ...
    segments: int = 1                       # 1 + the resumes appended
    partial_last_line: bool = False         # a run killed mid-write: its last line was cut and is ignored

    def __len__(self) -> int:
        return int(len(self.columns["index"]))

    def results_array(self, n: int, take: bool = False) -> np.ndarray:
        """The rows as RESULTS_DTYPE for a flight of n measurements (the rest OUTCOME_PENDING). `take`: the
        columns are moved out (freed one by one as they are copied, so a long run is not held twice)."""
        out = np.zeros(n, RESULTS_DTYPE)
        k = min(len(self), n)
        for name in RESULTS_DTYPE.names or ():
            out[name][:k] = self.columns.pop(name)[:k] if take and name != "index" else self.columns[name][:k]
        return out


def _open_text(path: Path, error: type[Exception]) -> IO[str]:
    if not path.is_file():
        raise InputFileNotFound(f"results file {path} not found")
    try:
        return gzip.open(path, "rt", encoding="utf-8") if path.suffix == ".gz" else open(path, encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None


def _result_value(rec: dict[str, Any], key: str, where: str, error: type[Exception]) -> Any:
    if key not in rec:
        raise error(f"{where}: result field {key!r} missing")
    value = rec[key]
    ok = isinstance(value, int) if is_integer(key) else isinstance(value, (int, float))
    if not ok or isinstance(value, bool):
        raise error(f"{where}: result field {key!r} is {value!r}, expected "
                    f"{'an integer' if is_integer(key) else 'a number'} (edited by hand?)")
    return value


def _lines(fh: IO[str], path: Path, error: type[Exception]) -> Iterator[tuple[int, str]]:
    """The lines of a results file, numbered from 1; bounded (a file without newlines is not read whole); bytes
    that are not UTF-8 text, or a damaged .gz, are an `error` naming the file and line."""
    lineno = 0
    while True:
        try:
            line = fh.readline(MAX_HEADER_CHARS + 1)
        except (UnicodeDecodeError, OSError, EOFError, zlib.error) as exc:
            why = "not UTF-8 text" if isinstance(exc, UnicodeDecodeError) else f"cannot be read ({exc})"
            after = f" (after line {lineno})" if lineno else ""
            raise error(f"{path}: {why}{after}: not a results file, or damaged") from None
        if not line:
            return
        lineno += 1
        if len(line) > MAX_HEADER_CHARS:
            raise error(f"{path}:{lineno}: line longer than {MAX_HEADER_CHARS} characters (not a results file?)")
        yield lineno, line


def read_run(path: Path, error: type[Exception] = ResultsFileError, columns: Iterable[str] = COLUMNS,
             allow_partial: bool = False, header_keys: Iterable[str] = ()) -> RunRecords:
    """Parse a results file (.jsonl or .jsonl.gz). Every malformed line is an `error` naming the file, line
    and field: not JSON, no type, a result without one of `columns` or with a non-number, results out of
    order. `allow_partial`: a cut last line (no newline) is ignored instead (a resume re-runs it)."""
    path = Path(path)
    cols = tuple(dict.fromkeys(("index", *columns)))
    values: dict[str, list[Any]] = {c: [] for c in cols}
    parts: dict[str, list[np.ndarray]] = {c: [] for c in cols}   # values moved into arrays every FLUSH_ROWS
    count = 0
    header: dict[str, Any] | None = None
    run = RunRecords(path=path, header={}, columns={})
    with _open_text(path, error) as fh:
        for lineno, line in _lines(fh, path, error):
            where = f"{path}:{lineno}"
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError as exc:
                if allow_partial and not line.endswith("\n"):      # only the last line can lack one
                    run.partial_last_line = True
                    break
                raise error(f"{where}: not JSON ({exc.msg})") from None
            kind = rec.get("type") if isinstance(rec, dict) else None
            if not isinstance(kind, str):
                raise error(f"{where}: record without a 'type' field")
            if header is None:
                if kind != REC_HEADER:
                    raise error(f"{path}:1: the first line must be the run header")
                header = rec
            elif kind == REC_RESULT:
                row = [_result_value(rec, c, where, error) for c in cols]
                if row[0] != count:
                    raise error(f"{where}: result index {row[0]}, expected {count} "
                                "(results are written in measurement order)")
                for c, v in zip(cols, row):
                    values[c].append(v)
                count += 1
                if len(values["index"]) >= FLUSH_ROWS:     # Python numbers cost ~4x an array's bytes
                    _flush(values, parts)
            elif kind == REC_STATS:
                run.stats = rec
            else:
                run.segments += kind == REC_RESUME
                run.records.append(rec)
    if header is None:
        raise error(f"{path}:1: the first line must be the run header")
    for key in header_keys:
        if key not in header:
            raise error(f"{path}:1: header field {key!r} missing")
    run.header = header
    _flush(values, parts)
    run.columns = {c: _joined(p, c) for c, p in parts.items()}
    return run


def _joined(parts: list[np.ndarray], column: str) -> np.ndarray:
    """One column from its pieces, freed as they are copied."""
    out = np.empty(sum(len(p) for p in parts), column_dtype(column))
    k = 0
    while parts:
        p = parts.pop(0)
        out[k:k + len(p)] = p
        k += len(p)
    return out


#: rows parsed before they move from Python lists into arrays (bounds the reader's memory)
FLUSH_ROWS = 1 << 13


def _flush(values: dict[str, list[Any]], parts: dict[str, list[np.ndarray]]) -> None:
    if values and next(iter(values.values())):
        for c, v in values.items():
            parts[c].append(np.asarray(v, dtype=column_dtype(c)))
            v.clear()


def _count_results(fh: IO[str]) -> int:
    prefix = json.dumps({"type": REC_RESULT})[:-1]
    lines = iter(lambda: fh.readline(MAX_HEADER_CHARS), "")      # bounded: no line is read whole
    return sum(1 for line in lines if line.startswith(prefix) and line.endswith("}\n"))


# ------------------------------------------------------------------------------------------ opening
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


#: longest header line (and read chunk) of a results file [characters]
MAX_HEADER_CHARS = 1 << 20


def describe_existing(path: Path) -> str | None:
    """Why `path` must not be overwritten silently (None if it may): an unfinished run, or not a results file.
    A complete run (every measurement has a line) may be replaced: it is finished, nothing is lost that a
    re-run would not write again."""
    try:
        if not path.is_file() or path.stat().st_size == 0:
            return None
        with open(path, encoding="utf-8", errors="replace") as fh:
            first = fh.readline(MAX_HEADER_CHARS + 1)      # bounded: a file without newlines is not read whole
            try:
                header = json.loads(first) if len(first) <= MAX_HEADER_CHARS else None
            except json.JSONDecodeError:
                header = None
            if not isinstance(header, dict) or header.get("type") != REC_HEADER or "n_measurements" not in header:
                return "it is not a uwb-hil results file (its first line is not a run header)"
            n = _count_results(fh)
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
            raise InputFileNotFound(f"results file {self.path} not found")
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
