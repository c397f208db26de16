"""Crazyflie micro-SD card deck event logs (Bitcraze's event-based binary format) -> decoded event tables.

Layout (written from the format's description, see docs/data-formats.md):

    byte 0      magic 0xBC
    uint16      version: 1 = uint32 millisecond timestamps, 2 = uint64 microsecond timestamps
    uint16      number of event types; per type: uint16 id, NUL-terminated name, uint16 variable count,
                per variable a NUL-terminated `name(T)`, T a Python struct letter
    records     until the last 4 bytes: uint16 event id, timestamp, the packed little-endian values
    uint32      CRC-32 (zlib) of every byte before it

Records of different types interleave, each type has a fixed size, so the stream is walked once to find
the record boundaries (a tight loop: read the id, jump by its size), then every type's records are
gathered at once into a numpy structured array. `read_usd_log` returns a `UsdLog`; turning it into a
`Flight` is harness/flight/formats/cf_usd_flight.py. Every refusal is a RecordingError naming the file
and the byte offset.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.flight.formats.common import RecordingError

MAGIC = 0xBC
VERSIONS = {1: ("<u4", 1000), 2: ("<u8", 1)}     # timestamp dtype, microseconds per tick
MAX_EVENT_TYPES = 1024                          # a header announcing more is not a log (or is corrupt)
MAX_NAME_BYTES = 256
# struct letters the firmware's loggable types use -> numpy little-endian dtypes
TYPE_LETTERS = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "l": "<i4", "L": "<u4",
                "q": "<i8", "Q": "<u8", "e": "<f2", "f": "<f4", "d": "<f8", "?": "u1", "c": "S1"}
CRC_BYTES = 4


@dataclass(frozen=True)
class EventType:
    """One declared event type: its id, name, variable names and the packed record dtype."""

    id: int
    name: str
    variables: tuple[str, ...]
    letters: str
    header_offset: int            # where its declaration starts in the file

    def values_dtype(self, time_bytes: int) -> np.dtype:
        """The variables of one whole record (id and timestamp skipped), packed: no alignment padding."""
        formats = [np.dtype(TYPE_LETTERS[c]) for c in self.letters]
        offsets = list(np.cumsum([2 + time_bytes] + [f.itemsize for f in formats]))
        return np.dtype({"names": list(self.variables), "formats": formats, "offsets": offsets[:-1],
                         "itemsize": int(offsets[-1])})


@dataclass
class UsdLog:
    """A decoded log, per event name: the timestamps (int64 microseconds), a structured array of the
    variables (native byte order) and the byte offset of every record (for errors that name where the bad
    record is)."""

    path: Path
    version: int
    types: dict[int, EventType]
    events: dict[str, np.ndarray] = field(default_factory=dict)
    times: dict[str, np.ndarray] = field(default_factory=dict)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    crc_ok: bool = True
    crc_message: str = ""          # the mismatch, when loaded with ignore_crc
    records_start: int = 0
    size: int = 0

    def count(self, name: str) -> int:
        return int(len(self.events[name])) if name in self.events else 0


def is_cf_usd(path: Path) -> bool:
    """The loaders' dispatch: the magic byte 0xBC. No text recording can start with it (a UTF-8 continuation
    byte) nor a .npz (a zip: 'PK'), so a bad header after it gets the uSD reader's own reason."""
    try:
        with open(path, "rb") as f:
            return f.read(1) == bytes([MAGIC])
    except OSError:
        return False


def read_usd_log(path: Path | str, *, ignore_crc: bool = False) -> UsdLog:
    """Decode a whole log. A CRC mismatch is refused unless ignore_crc (then it is kept in crc_message)."""
    path = Path(path)
    data = path.read_bytes()
    index = index_records(data, path)
    crc_message = ""
    if not index.crc_ok:
        reason, offset = crc_mismatch(data)
        if not ignore_crc:
            raise RecordingError(reason + " (pass --ignore-crc to load it anyway)", path=path, offset=offset)
        crc_message = f"{path}, byte offset {offset}: {reason}"
    log = UsdLog(path=path, version=index.version, types=index.types, crc_ok=index.crc_ok, crc_message=crc_message,
                 records_start=index.records_start, size=len(data))
    buf = np.frombuffer(data, dtype=np.uint8)
    time_bytes = index.time_bytes
    for type_id, et in index.types.items():
        at = index.starts[index.ids == type_id]
        if at.size == 0:
            continue
        dt = et.values_dtype(time_bytes)
        raw = buf[at[:, None] + np.arange(dt.itemsize)]                    # (n, record size) bytes
        log.times[et.name] = index.stamps_us(raw[:, 2:2 + time_bytes])
        log.events[et.name] = _native(raw.reshape(-1).view(dt), et)
        log.offsets[et.name] = at
    return log


@dataclass(frozen=True)
class RecordIndex:
    """A log's header and where each record starts, with its event id: one walk, no payload decoded (what
    read_usd_log gathers the records by, and all cf_usd_summary needs)."""

    version: int
    types: dict[int, EventType]
    records_start: int
    crc_ok: bool
    starts: np.ndarray            # byte offset of every record (int64)
    ids: np.ndarray               # its event id (int64)

    @property
    def time_bytes(self) -> int:
        return _time_bytes(self.version)

    def stamps_us(self, stamp_bytes: np.ndarray) -> np.ndarray:
        """(n, time_bytes) uint8 timestamp fields -> int64 microseconds."""
        time_dtype, tick_us = VERSIONS[self.version]
        return np.ascontiguousarray(stamp_bytes).view(time_dtype)[:, 0].astype(np.int64) * tick_us


def _time_bytes(version: int) -> int:
    """Bytes of a record's timestamp in this log version."""
    return int(np.dtype(VERSIONS[version][0]).itemsize)


def index_records(data: bytes, path: Path) -> RecordIndex:
    """The header, the CRC check and the record walk of read_usd_log; its refusals (a CRC mismatch is only
    noted in crc_ok: the caller decides)."""
    version, types, start = parse_header(data, path)
    at = len(data) - CRC_BYTES
    crc_ok = struct.unpack_from("<I", data, at)[0] == zlib.crc32(data[:at]) & 0xFFFFFFFF
    try:
        starts = walk_records(data, start, at, types, _time_bytes(version), path)
    except RecordingError as exc:      # the more specific reason; a truncated file fails its CRC too
        if crc_ok:
            raise
        raise RecordingError(f"{exc.reason}; the CRC does not match either", path=path, offset=exc.offset) from None
    buf = np.frombuffer(data, dtype=np.uint8)
    ids = buf[starts].astype(np.int64) | (buf[starts + 1].astype(np.int64) << 8)
    return RecordIndex(version=version, types=types, records_start=start, crc_ok=crc_ok, starts=starts, ids=ids)


def _native(raw: np.ndarray, et: EventType) -> np.ndarray:
    """Packed little-endian records -> a compact native-endian structured array of the variables."""
    out = np.empty(len(raw), dtype=[(v, raw.dtype[v].newbyteorder("=")) for v in et.variables])
    for v in et.variables:
        out[v] = raw[v]
    return out


# ------------------------------------------------------------------------------------------ header
def parse_header(data: bytes, path: Path) -> tuple[int, dict[int, EventType], int]:
    """(version, event types by id, offset of the first record)."""
    if len(data) < 5 + CRC_BYTES or data[0] != MAGIC:
        raise RecordingError(f"not a Crazyflie uSD event log: expected magic byte 0xBC and a header, got "
                             f"{data[:1].hex() or 'an empty file'}", path=path, offset=0)
    version, n_types = struct.unpack_from("<HH", data, 1)
    if version not in VERSIONS:
        raise RecordingError(f"unknown log version {version} (expected 1 or 2)", path=path, offset=1)
    if not 0 < n_types <= MAX_EVENT_TYPES:
        raise RecordingError(f"implausible number of event types {n_types} (expected 1..{MAX_EVENT_TYPES})",
                             path=path, offset=3)
    end = len(data) - CRC_BYTES
    o = 5
    types: dict[int, EventType] = {}
    names: set[str] = set()
    for k in range(n_types):
        et, o = _event_type(data, o, end, path, k, n_types)
        if et.id in types or et.name in names:
            raise RecordingError(f"event type {et.name!r} (id {et.id}) declared twice", path=path,
                                 offset=et.header_offset)
        types[et.id] = et
        names.add(et.name)
    return version, types, o


def _event_type(data: bytes, o: int, end: int, path: Path, k: int, n: int) -> tuple[EventType, int]:
    at = o
    type_id = _u16(data, o, end, path, f"the id of event type {k + 1} of {n}")
    name, o = _cstring(data, o + 2, end, path, f"the name of event type {k + 1} of {n}")
    count = _u16(data, o, end, path, f"the variable count of event {name!r}")
    o += 2
    variables, letters = [], []
    for j in range(count):
        vo = o
        spec, o = _cstring(data, o, end, path, f"variable {j + 1} of {count} of event {name!r}")
        if len(spec) < 4 or spec[-3] != "(" or spec[-1] != ")" or spec[-2] not in TYPE_LETTERS:
            raise RecordingError(f"variable {spec!r} of event {name!r}: expected 'name(T)' with T one of "
                                 f"{''.join(TYPE_LETTERS)}", path=path, offset=vo)
        if spec[:-3] in variables:
            raise RecordingError(f"variable {spec[:-3]!r} of event {name!r} declared twice", path=path, offset=vo)
        variables.append(spec[:-3])
        letters.append(spec[-2])
    return EventType(type_id, name, tuple(variables), "".join(letters), at), o


def _u16(data: bytes, o: int, end: int, path: Path, what: str) -> int:
    if o + 2 > end:
        raise RecordingError(f"the header ends inside {what} (the type count runs beyond the file)", path=path,
                             offset=o)
    return int(struct.unpack_from("<H", data, o)[0])


def _cstring(data: bytes, o: int, end: int, path: Path, what: str) -> tuple[str, int]:
    stop = data.find(b"\0", o, min(end, o + MAX_NAME_BYTES + 1))
    if stop < 0:
        reason = "the header runs beyond the file" if end - o <= MAX_NAME_BYTES else \
            f"no NUL within {MAX_NAME_BYTES} bytes"
        raise RecordingError(f"unterminated string in {what} ({reason})", path=path, offset=o)
    try:
        text = data[o:stop].decode("ascii")
    except UnicodeDecodeError:
        raise RecordingError(f"{what} is not ASCII: {data[o:stop]!r}", path=path, offset=o) from None
    if not text or not text.isprintable():
        raise RecordingError(f"{what} is empty or not printable: {text!r}", path=path, offset=o)
    return text, stop + 1


# ------------------------------------------------------------------------------------------ records
def walk_records(data: bytes, start: int, end: int, types: dict[int, EventType], time_bytes: int,
                 path: Path) -> np.ndarray:
    """Byte offsets of every record in [start, end): one tight loop, each step reads the 2-byte id and
    jumps by that type's record size (an undeclared id jumps past the end and is explained below)."""
    beyond = end - start + 1
    size = [beyond] * (1 << 16)
    for et in types.values():
        size[et.id] = 2 + time_bytes + struct.calcsize("<" + et.letters)
    starts: list[int] = []
    append = starts.append
    o, limit = start, end - 1             # a record starting at end - 1 cannot hold its id
    while o < limit:
        append(o)
        o += size[data[o] | (data[o + 1] << 8)]
    if o == end:
        return np.asarray(starts, dtype=np.int64)
    _record_error(data, starts[-1] if o > end else o, end, size, types, path)
    raise AssertionError("unreachable")  # pragma: no cover


def _record_error(data: bytes, o: int, end: int, size: list[int], types: dict[int, EventType],
                  path: Path) -> None:
    """Explain why the walk stopped at record offset o."""
    if o + 2 > end:
        raise RecordingError(f"truncated record: {end - o} byte before the CRC, no room for an event id",
                             path=path, offset=o)
    type_id = data[o] | (data[o + 1] << 8)
    if type_id not in types:
        declared = ", ".join(f"{t.id} {t.name}" for t in sorted(types.values(), key=lambda t: t.id))
        raise RecordingError(f"record with undeclared event id {type_id} (declared: {declared}): its size is "
                             "unknown, the log cannot be followed past it (corrupt or truncated)",
                             path=path, offset=o)
    raise RecordingError(f"truncated record of event {types[type_id].name!r}: needs {size[type_id]} bytes, "
                         f"{end - o} left before the CRC", path=path, offset=o)


def crc_mismatch(data: bytes) -> tuple[str, int]:
    """Why the stored CRC-32 does not match, and the offset to name: the corrupted byte when one byte
    explains the mismatch, else the CRC's own offset."""
    at = len(data) - CRC_BYTES
    stored = struct.unpack_from("<I", data, at)[0]
    computed = zlib.crc32(data[:at]) & 0xFFFFFFFF
    from harness.flight.formats.crc_locate import candidate_offsets
    where = candidate_offsets(data[:at], stored ^ computed)
    head = f"CRC-32 mismatch (stored 0x{stored:08x} at offset {at}, computed 0x{computed:08x})"
    if len(where) == 1:
        return f"{head}: one corrupted byte at this offset explains it", where[0]
    if 1 < len(where) <= 3:
        return f"{head}: one corrupted byte at offset {' or '.join(map(str, where))} would explain it", at
    return f"{head}: the log is corrupt somewhere in bytes 0..{at + CRC_BYTES - 1}", at


def main(argv: list[str] | None = None) -> int:
    """`python -m harness.flight.formats.cf_usd LOG...`: the event types and record counts of each log, its
    CRC, and the time to decode it (best of 5)."""
    import argparse
    import sys
    import time
    ap = argparse.ArgumentParser(prog="python -m harness.flight.formats.cf_usd", description=main.__doc__)
    ap.add_argument("logs", nargs="+", help="Crazyflie uSD event logs")
    args = ap.parse_args(argv)
    for name in args.logs:
        try:
            best = float("inf")
            for _ in range(5):
                t0 = time.perf_counter()
                log = read_usd_log(name, ignore_crc=True)
                best = min(best, time.perf_counter() - t0)
        except (RecordingError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        records = sum(log.count(n) for n in log.events)
        print(f"{name}: version {log.version}, {log.size / 1e6:.2f} MB, {records} records, CRC "
              f"{'ok' if log.crc_ok else 'MISMATCH: ' + log.crc_message}; decoded in {1000 * best:.0f} ms "
              f"({log.size / 1e6 / best:.0f} MB/s)")
        for et in sorted(log.types.values(), key=lambda e: e.id):
            print(f"  {et.id:3d} {et.name:<18} {log.count(et.name):7d}  {', '.join(et.variables)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
