"""What a Crazyflie uSD log holds, without decoding it: the event types, their record counts and the time span.

Planning (the campaign's recorded section, `make real-flights`) asks of every log only whether it carries
IMU, UWB and ToF ranger readings. The header alone cannot say (the 0426 logs declare estTOF and hold none),
but the record walk of the reader can: `usd_summary` reads the header, checks the CRC and walks the records
(cf_usd.index_records), counting each event id and reading the timestamps, and gathers no payload: about half
of a full decode (read_usd_log). A log that cannot be walked raises the reader's RecordingError naming the file.

Each file is scanned once per process: the summary is cached on the file's identity (resolved path, size,
modification time in ns), so a rewritten file is scanned anew.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from harness.flight.formats.cf_usd import index_records
from harness.flight.formats.cf_usd_flight import ACC, GYRO, TDOA, TOF, TWR
from harness.flight.formats.common import RecordingError

#: a file's identity for the caches of decoded logs: (resolved path, size in bytes, st_mtime_ns). A rewrite that
#: keeps both the size and the modification time (same file-system clock tick) is not noticed.
FileStamp = tuple[str, int, int]


def file_stamp(path: Path | str) -> FileStamp:
    """The file's identity as the caches key it; FileNotFoundError for a missing file."""
    resolved = Path(path).resolve()
    st = resolved.stat()
    return str(resolved), int(st.st_size), int(st.st_mtime_ns)


@dataclass(frozen=True)
class UsdSummary:
    """A uSD log's declared event types (in declaration order) with their record counts, its version, CRC and the
    span of its timestamps."""

    path: Path                                  # resolved
    size: int                                   # bytes
    version: int
    crc_ok: bool
    counts: tuple[tuple[str, int], ...]         # (event name, records) of every declared type
    t_first_us: int | None                      # earliest and latest record timestamp (None: no records)
    t_last_us: int | None

    def count(self, name: str) -> int:
        return dict(self.counts).get(name, 0)

    @property
    def has_imu(self) -> bool:
        """Both accelerometer and gyroscope records (estAcceleration, estGyroscope)."""
        return self.count(ACC) > 0 and self.count(GYRO) > 0

    @property
    def has_tof_readings(self) -> bool:
        """ToF ranger readings (a flow deck): estTOF records, not only its declaration."""
        return self.count(TOF) > 0

    @property
    def uwb(self) -> str | None:
        """"tdoa" (estTDOA records), else "twr" (estDistance), else None: as load_cf_usd picks the UWB stream.
        TDoA2 or TDoA3 is the loaded flight's meta["tdoa_mode"]: it needs the anchor file and the payloads."""
        return "tdoa" if self.count(TDOA) else "twr" if self.count(TWR) else None

    @property
    def duration_s(self) -> float:
        """From the first record's timestamp to the last one's."""
        if self.t_first_us is None or self.t_last_us is None:
            return 0.0
        return (self.t_last_us - self.t_first_us) * 1e-6


def usd_summary(path: Path | str) -> UsdSummary:
    """The summary of one log, scanned at most once per file identity (file_stamp) in this process. Refusals are
    read_usd_log's (a CRC mismatch is not one: crc_ok), naming the path as given."""
    resolved, size, mtime_ns = file_stamp(path)
    try:
        return _scan(resolved, size, mtime_ns)
    except RecordingError as exc:
        raise RecordingError(exc.reason, path=path, offset=exc.offset) from None


# lru_cache on a pure function of the file's identity rather than a cache object passed along: the callers
# (campaign plan, make real-flights) are far apart and only ever want the current file's answer; the cache is
# bounded and keeps no state of ours (no module-level mutable global). size and mtime_ns only key it.
@lru_cache(maxsize=64)
def _scan(path: str, size: int, mtime_ns: int) -> UsdSummary:
    data = Path(path).read_bytes()
    index = index_records(data, Path(path))
    counts = np.bincount(index.ids, minlength=max(index.types, default=0) + 1) if index.ids.size else None
    first = last = None
    if index.starts.size:
        buf = np.frombuffer(data, dtype=np.uint8)
        stamps = index.stamps_us(buf[index.starts[:, None] + 2 + np.arange(index.time_bytes)])
        first, last = int(stamps.min()), int(stamps.max())
    return UsdSummary(path=Path(path), size=len(data), version=index.version, crc_ok=index.crc_ok,
                      counts=tuple((et.name, int(counts[i]) if counts is not None else 0)
                                   for i, et in index.types.items()),
                      t_first_us=first, t_last_us=last)
