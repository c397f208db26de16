"""Shared pieces of the recorded-data readers: the error type, a strict CSV table, time and quaternion helpers.

Every reader goes through `read_csv_table` so a malformed file is reported the same way everywhere:
file, line number, column name and what was expected. Parsing is vectorised (numpy) on the good path;
only when that fails do we walk the column again to find the offending cell.
"""

from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Iterator, Sequence

import numpy as np

from harness.errors import InputFileNotFound
from harness.flight.data import Anchors, FlightError, ImuStream


class RecordingError(FlightError):
    """A recording or anchor file is malformed. Names the file, the line (text) or byte offset (binary) and/or
    field, and what was expected."""

    def __init__(self, message: str, *, path: Path | str | None = None, line: int | None = None,
                 field: str | None = None, offset: int | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.line = line
        self.field = field
        self.offset = offset        # byte offset, for binary files
        self.reason = message
        where = str(path) if path is not None else "<recording>"
        if line is not None:
            where += f", line {line}"
        if offset is not None:
            where += f", byte offset {offset}"
        if field is not None:
            where += f", field {field!r}"
        super().__init__(f"{where}: {message}")


#: longest line a recording may have [characters]: a file without newlines fails at once, in small memory
MAX_LINE_CHARS = 1 << 16
#: how much of the input an error message quotes
QUOTE_CHARS = 100


class RecordingWarning(UserWarning):
    """Something in a recording was left out (e.g. a last line without its newline); the CLI prints it."""


def quote(text: str, n: int = QUOTE_CHARS) -> str:
    """repr() of at most n characters of input, marked when cut."""
    return repr(text[:n]) + (f"... ({len(text)} characters)" if len(text) > n else "")


def bounded_lines(f: IO[str], path: Path) -> Iterator[str]:
    """The lines of a text file, each at most MAX_LINE_CHARS long (else a RecordingError at once, quoting its
    start). A last line without its newline may have been cut while written: dropped, with a RecordingWarning."""
    n = 0
    while True:
        line = f.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        n += 1
        if line.endswith("\n"):
            yield line
            continue
        if len(line) > MAX_LINE_CHARS:
            raise RecordingError(f"line longer than {MAX_LINE_CHARS} characters (not a text recording?), starting "
                                 f"{quote(line)}", path=path, line=n)
        if line.strip():
            warnings.warn(RecordingWarning(f"{path}, line {n}: the last line has no newline (the file may have "
                                           "been cut while written): dropped"), stacklevel=2)
        return


@dataclass(frozen=True)
class CsvTable:
    """A CSV file with a header: every data row has exactly len(header) cells (checked on read)."""

    path: Path
    header: tuple[str, ...]
    rows: list[list[str]]
    lines: np.ndarray   # (N,) file line number of each data row

    def __len__(self) -> int:
        return len(self.rows)

    def column(self, name: str) -> list[str]:
        idx = self.header.index(name)
        return [r[idx] for r in self.rows]

    def stream_length(self, names: Sequence[str]) -> int:
        """Rows used by a stream of columns that may end early (trailing empty cells, as in the UTIL CSVs).

        The named cells of a row are either all set or all empty, and once a stream has ended (an empty
        row) it stays empty; anything else is a truncated or corrupted row.
        """
        filled = np.stack([np.fromiter((c.strip() != "" for c in self.column(n)), dtype=bool, count=len(self))
                           for n in names], axis=1) if len(self) else np.zeros((0, len(names)), dtype=bool)
        partial = np.nonzero(filled.any(axis=1) & ~filled.all(axis=1))[0]
        if partial.size:
            k = int(partial[0])
            empty = [n for n, f in zip(names, filled[k]) if not f]
            raise RecordingError(f"cell is empty while the rest of the stream ({', '.join(names)}) is set "
                                 "(truncated or corrupted row)", path=self.path, line=int(self.lines[k]),
                                 field=empty[0])
        row_set = filled.all(axis=1) if len(names) else np.zeros(len(self), dtype=bool)
        n = int(np.argmin(row_set)) if not row_set.all() else len(self)
        later = np.nonzero(row_set[n:])[0]
        if later.size:
            k = n + int(later[0])
            raise RecordingError(f"the stream ({', '.join(names)}) ended on line {int(self.lines[n])} but "
                                 "resumes here; empty cells are only allowed at the end of a stream",
                                 path=self.path, line=int(self.lines[k]), field=names[0])
        return n

    def floats(self, name: str, n: int | None = None, finite: bool = True) -> np.ndarray:
        """The first n cells of a column as float64; a non-numeric (or NaN/Inf, if finite) cell is an error."""
        cells = self.column(name)[: len(self) if n is None else n]
        try:
            values = np.array(cells, dtype=np.float64) if cells else np.zeros(0)
        except ValueError:
            for k, c in enumerate(cells):
                try:
                    float(c)
                except ValueError:
                    raise RecordingError(f"expected a number, got {quote(c)}", path=self.path,
                                         line=int(self.lines[k]), field=name) from None
            raise  # pragma: no cover - numpy and float() agree on what a number is
        if finite:
            bad = np.nonzero(~np.isfinite(values))[0]
            if bad.size:
                k = int(bad[0])
                raise RecordingError(f"expected a finite number, got {quote(cells[k].strip())} "
                                     f"({bad.size} non-finite cell(s) in this column)", path=self.path,
                                     line=int(self.lines[k]), field=name)
        return values

    def ints(self, name: str, n: int | None = None, lo: int = 0, hi: int = 255) -> np.ndarray:
        """Integer ids written as integers or integral floats ("4", "4.0"), within [lo, hi]."""
        values = self.floats(name, n)
        bad = np.nonzero((values != np.round(values)) | (values < lo) | (values > hi))[0]
        if bad.size:
            k = int(bad[0])
            raise RecordingError(f"expected an integer id in [{lo}, {hi}], got {quote(self.column(name)[k])}",
                                 path=self.path, line=int(self.lines[k]), field=name)
        return values.astype(np.int64)


def read_csv_table(path: Path, what: str) -> CsvTable:
    """Read a headed CSV file strictly. `what` names the expected content in error messages."""
    path = Path(path)
    if not path.exists():
        raise InputFileNotFound(f"{what} {path} not found")
    if path.is_dir():
        raise RecordingError(f"expected a {what} file, got a directory", path=path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(bounded_lines(f, path))
            header: list[str] | None = None
            rows: list[list[str]] = []
            lines: list[int] = []
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue  # blank lines carry nothing; skipping them loses nothing
                if header is None:
                    header = [c.strip() for c in row]
                    continue
                if len(row) != len(header):
                    raise RecordingError(f"expected {len(header)} fields (as in the header), got {len(row)} "
                                         "(truncated or malformed line)", path=path, line=reader.line_num)
                rows.append(row)
                lines.append(reader.line_num)
    except UnicodeDecodeError as exc:
        raise RecordingError(f"not a UTF-8 text file ({exc.reason} at byte {exc.start})", path=path) from None
    except csv.Error as exc:
        raise RecordingError(f"malformed CSV: {exc}", path=path) from None
    if header is None:
        raise RecordingError(f"empty file, expected a {what} with a header line", path=path, line=1)
    if len(set(header)) != len(header):
        raise RecordingError(f"duplicate column names in the header: {quote(','.join(header))}", path=path, line=1)
    return CsvTable(path=path, header=tuple(header), rows=rows, lines=np.asarray(lines, dtype=np.int64))


def require_columns(table: CsvTable, expected: Sequence[str], what: str) -> None:
    missing = [c for c in expected if c not in table.header]
    if missing:
        raise RecordingError(f"not a {what}: missing column(s) {missing}; expected header "
                             f"{','.join(expected)}", path=table.path, line=1)


def seconds_to_us(t_s: np.ndarray) -> np.ndarray:
    """Seconds -> int64 microseconds, rounded to the nearest microsecond (the data has 1 us resolution)."""
    return np.rint(np.asarray(t_s, dtype=np.float64) * 1e6).astype(np.int64)


def check_not_backwards(t: np.ndarray, table: CsvTable, field: str, rows: np.ndarray | None = None) -> None:
    """Refuse a stream whose time goes backwards; name the first offending line."""
    bad = np.nonzero(np.diff(t) < 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        row = int(rows[k]) if rows is not None else k
        prev = int(rows[k - 1]) if rows is not None else k - 1
        raise RecordingError(f"time goes backwards: {t[k]} after {t[k - 1]} on line {int(table.lines[prev])} "
                             f"({bad.size} backward step(s) in this stream)", path=table.path,
                             line=int(table.lines[row]), field=field)


def repeated_rows(*columns: np.ndarray) -> np.ndarray:
    """Mask of rows identical (every column) to the row before: logging duplicates, dropped and counted."""
    n = len(columns[0])
    if n == 0:
        return np.zeros(0, dtype=bool)
    same = np.ones(n - 1, dtype=bool)
    for c in columns:
        c = np.asarray(c)
        d = c[1:] == c[:-1]
        same &= d.all(axis=tuple(range(1, d.ndim))) if d.ndim > 1 else d
    return np.concatenate([[False], same])


def anchor_positions(anchors: Anchors, ids: np.ndarray) -> np.ndarray:
    """Positions of the given (known) anchor ids, vectorised."""
    lut = np.full(int(max(anchors.ids.max(), ids.max())) + 1, -1, dtype=np.int64)
    lut[anchors.ids.astype(np.int64)] = np.arange(len(anchors.ids))
    k = lut[ids.astype(np.int64)]
    if np.any(k < 0):
        raise FlightError(f"unknown anchor id(s) {sorted(set(ids[k < 0].tolist()))}")
    return anchors.positions[k]


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z), body -> world -> (N, 3, 3) rotation matrices."""
    w, x, y, z = (q[:, k] for k in range(4))
    r = np.empty((len(q), 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z)
    r[:, 0, 1] = 2 * (x * y - w * z)
    r[:, 0, 2] = 2 * (x * z + w * y)
    r[:, 1, 0] = 2 * (x * y + w * z)
    r[:, 1, 1] = 1 - 2 * (x * x + z * z)
    r[:, 1, 2] = 2 * (y * z - w * x)
    r[:, 2, 0] = 2 * (x * z - w * y)
    r[:, 2, 1] = 2 * (y * z + w * x)
    r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def distinct_poses(t: np.ndarray, table: CsvTable, field: str, *columns: np.ndarray) -> tuple[np.ndarray, int]:
    """Indices of the pose rows to keep (logging duplicates of the row before dropped) and how many were
    dropped; two different poses at one time are refused, naming the line."""
    rep = repeated_rows(t, *columns)
    keep = np.nonzero(~rep)[0]
    same_t = np.nonzero(np.diff(t[keep]) == 0)[0]
    if same_t.size:
        k = int(keep[same_t[0] + 1])
        raise RecordingError(f"two different poses with the same timestamp (expected strictly increasing {field})",
                             path=table.path, line=int(table.lines[k]), field=field)
    return keep, int(rep.sum())


def normalised_quats(q: np.ndarray, table: CsvTable | None, field: str, path: Path | None = None,
                     rows: np.ndarray | None = None, tol: float = 0.01) -> np.ndarray:
    """Normalise quaternions; one whose norm is off by more than tol is corrupt, not rounding."""
    norm = np.linalg.norm(q, axis=1)
    bad = np.nonzero(np.abs(norm - 1.0) > tol)[0]
    if bad.size:
        k = int(bad[0])
        line = None
        if table is not None:
            line = int(table.lines[int(rows[k]) if rows is not None else k])
        raise RecordingError(f"quaternion norm {norm[k]:.4f} is not 1 (expected a unit quaternion)",
                             path=table.path if table is not None else path, line=line, field=field)
    return q / norm[:, None]


def imu_on_gyro_times(ta: np.ndarray, acc: np.ndarray, tg: np.ndarray, gyro: np.ndarray,
                      dropped: dict[str, int]) -> ImuStream:
    """Accelerometer and gyro streams (SI) -> one ImuStream on the gyro's timestamps: the accelerometer
    linearly interpolated to them (first sample of a repeated time kept); gyro samples outside the
    accelerometer's span are dropped and counted in dropped["gyro_outside_acc_span"]."""
    _, first = np.unique(ta, return_index=True)   # interpolation needs increasing abscissae
    ta, acc = ta[first], acc[first]
    inside = (tg >= ta[0]) & (tg <= ta[-1])
    if (~inside).any():
        dropped["gyro_outside_acc_span"] = int((~inside).sum())
    tg, gyro = tg[inside], gyro[inside]
    acc_i = np.stack([np.interp(tg.astype(np.float64), ta.astype(np.float64), acc[:, k]) for k in range(3)], axis=1)
    return ImuStream(t_us=tg.astype(np.int64), acc=acc_i, gyro=gyro)
