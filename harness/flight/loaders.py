"""Recorded flights -> `Flight`: `load_recording` picks the reader from the file's content.

    UTIL flight CSV, reduced 8 columns or official 27 columns   harness/flight/formats/util.py
    rcv_twr sequence directory (anchor.yaml, anchor_K.csv, gt.csv)  harness/flight/formats/rcv_twr.py
    native .npz (this project's format)                         harness/flight/native.py
    anchor files (anchors.csv, anchor_constN.npz/.txt, anchor.yaml) harness/flight/formats/anchors.py

Malformed input raises `RecordingError` (a FlightError, so a ValueError) naming the file, the line
and/or field and what was expected; a missing file is FileNotFoundError with the path. What is refused
and what is dropped (and counted in `flight.meta["dropped"]`) is listed in docs/data-formats.md.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.flight.formats.anchors import (load_anchor_yaml, load_anchors, load_anchors_csv, load_survey_npz,
                                            load_survey_txt)
from harness.flight.formats.common import RecordingError
from harness.flight.formats.rcv_twr import (ANCHOR_COLUMNS, DEFAULT_ANCHOR_OFFSET, GT_COLUMNS, is_rcv_twr_dir,
                                            load_rcv_twr)
from harness.flight.formats.util import constellation_from_name, load_util_csv, util_layout
from harness.flight.model import Anchors, Flight, FlightError
from harness.flight.native import is_native, load_flight, save_flight

__all__ = ["RecordingError", "load_recording", "load_anchors", "load_anchors_csv", "load_survey_npz",
           "load_survey_txt", "load_anchor_yaml", "load_util_csv", "load_rcv_twr", "load_flight", "save_flight",
           "find_anchor_file", "time_slice", "DEFAULT_ANCHOR_OFFSET"]

AnchorsArg = Anchors | Path | str | None


def load_recording(path: Path | str, anchors: AnchorsArg = None, *, constellation: int | None = None,
                   anchor_offset: tuple[float, float, float] | None = DEFAULT_ANCHOR_OFFSET) -> Flight:
    """Load any supported recording.

    anchors: an `Anchors`, or an anchor file. UTIL CSVs need one; when None, an `anchors.csv` next to the
        recording or up to two directories above it is used. The constellation of a multi-constellation
        anchors.csv is `constellation`, else the `constN` in the recording's file name.
        For rcv_twr, None means the sequence's anchor.yaml; for a native file, given anchors replace the
        stored ones.
    anchor_offset: rcv_twr only, added to the anchor positions (the source's antenna offset; None = none).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"recording {path} not found")
    if path.is_dir():
        if not is_rcv_twr_dir(path):
            raise RecordingError("this directory is not a recording: expected an rcv_twr sequence (anchor.yaml, "
                                 "anchor_K.csv, gt.csv)", path=path)
        given = _anchors(anchors, path, constellation) if anchors is not None else None
        return load_rcv_twr(path, given, anchor_offset=anchor_offset)
    if path.suffix.lower() == ".npz":
        if not is_native(path):
            hint = (" (this is a UTIL anchor survey: pass it as the anchors)"
                    if _has_members(path, {"an_pos.npy", "an_quat.npy"}) else "")
            raise RecordingError(f"not a native uwb-hil recording{hint}", path=path)
        flight = load_flight(path)
        if anchors is not None:
            flight = replace(flight, anchors=_anchors(anchors, path, constellation))
            try:
                flight.validate()
            except FlightError as exc:
                raise RecordingError(f"with the given anchors: {exc}", path=path) from None
        return flight
    header = _header(path)
    if util_layout(header) is not None:
        return load_util_csv(path, _util_anchors(anchors, path, constellation))
    if header == ANCHOR_COLUMNS or header == GT_COLUMNS:
        raise RecordingError("this is one file of an rcv_twr sequence: pass the sequence directory", path=path)
    if "anchor_id" in header:
        raise RecordingError("this is an anchor file: pass it as the anchors, with a recording", path=path)
    raise RecordingError("unknown recording format: expected a UTIL flight CSV (8 or 27 columns), an rcv_twr "
                         f"sequence directory or a native .npz; the header is {','.join(header)}", path=path, line=1)


def time_slice(flight: Flight, start_s: float, end_s: float) -> Flight:
    """The part of a flight between start_s and end_s seconds after its first UWB measurement
    (short test replays, train/evaluation splits). Truth keeps one sample beyond each end so it still
    interpolates over the whole slice."""
    if not end_s > start_s:
        raise ValueError(f"time_slice needs end_s > start_s, got {start_s}, {end_s}")
    t0 = int(flight.uwb.t_us[0]) if len(flight.uwb) else 0
    lo, hi = t0 + int(round(start_s * 1e6)), t0 + int(round(end_s * 1e6))
    u = flight.uwb
    m = (u.t_us >= lo) & (u.t_us < hi)
    if not m.any():
        raise ValueError(f"{flight.name}: no UWB measurement between {start_s} s and {end_s} s")
    uwb = replace(u, t_us=u.t_us[m], anchor_a=u.anchor_a[m], anchor_b=u.anchor_b[m], value=u.value[m],
                  true_value=u.true_value[m] if u.true_value is not None else None)
    tr = flight.truth
    i0 = max(int(np.searchsorted(tr.t_us, lo, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(tr.t_us, hi, side="left")) + 1, len(tr.t_us))
    truth = replace(tr, t_us=tr.t_us[i0:i1], pos=tr.pos[i0:i1],
                    quat=tr.quat[i0:i1] if tr.quat is not None else None,
                    vel=tr.vel[i0:i1] if tr.vel is not None else None)
    imu = flight.imu
    if imu is not None:
        k = (imu.t_us >= lo) & (imu.t_us < hi)
        imu = replace(imu, t_us=imu.t_us[k], acc=imu.acc[k], gyro=imu.gyro[k])
    meta = dict(flight.meta, slice_s=[float(start_s), float(end_s)])
    return Flight(name=f"{flight.name}[{start_s:g}-{end_s:g}s]", anchors=flight.anchors, uwb=uwb, truth=truth,
                  imu=imu, meta=meta)


def find_anchor_file(recording: Path) -> Path | None:
    """An `anchors.csv` in the recording's directory or up to two levels above it."""
    here = recording.resolve().parent
    for d in (here, here.parent, here.parent.parent):
        if (d / "anchors.csv").is_file():
            return d / "anchors.csv"
    return None


def _util_anchors(anchors: AnchorsArg, path: Path, constellation: int | None) -> Anchors:
    if anchors is None:
        found = find_anchor_file(path)
        if found is None:
            raise RecordingError("no anchors given and no anchors.csv found next to the recording: pass the "
                                 "anchor file (--anchors anchors.csv or a UTIL survey anchor_constN.npz/.txt)",
                                 path=path)
        anchors = found
    return _anchors(anchors, path, constellation)


def _anchors(anchors: AnchorsArg, recording: Path, constellation: int | None) -> Anchors:
    if isinstance(anchors, Anchors):
        return anchors
    assert anchors is not None
    return load_anchors(Path(anchors), constellation if constellation is not None
                        else constellation_from_name(recording))


def _header(path: Path) -> tuple[str, ...]:
    """The first non-blank line of a text file, split on commas (cheap: the dispatch reads nothing else)."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            for line in f:
                if line.strip():
                    return tuple(c.strip() for c in line.rstrip("\r\n").split(","))
    except UnicodeDecodeError:
        raise RecordingError("not a text file: expected a CSV recording (or a .npz / directory)", path=path) from None
    raise RecordingError("empty file, expected a recording with a header line", path=path, line=1)


def _has_members(path: Path, names: set[str]) -> bool:
    import zipfile
    try:
        with zipfile.ZipFile(path) as z:
            return names <= set(z.namelist())
    except (zipfile.BadZipFile, OSError):
        return False

