"""The RCV drone TWR recordings (github cjhhalla/RCV_uwb_dataset, arXiv 2407.03890) -> Flight (KIND_TWR).

A sequence is a directory:
* `anchor.yaml`: anchor positions [m] and orientation quaternions [x, y, z, w] (see formats/anchors.py);
* `anchor_K.csv`: TWR ranges to anchor K (1 cm resolution) with the tag pose the source matched to each
  (nearest motion-capture sample within 10 ms); the columns read are RANGE_COLUMNS (others, such as the
  received power, are ignored); Time is a wall-clock datetime string;
* `gt.csv`: the whole motion-capture stream (GT_COLUMNS).

The four anchors' ranges are merged in time order into one TWR stream (anchor id = K). Times become
microseconds since the earliest timestamp of the sequence. Truth is gt.csv (pose as recorded, taken as the
tag: the source's analysis does the same). `true_value` uses the pose matched in the anchor file itself.

The source's analysis adds an antenna offset (world frame) to the surveyed anchor positions; the data
folder's README.md states it, and by default (`anchor_offset`) it is read from there (the README beside the
sequence folder or one level up), never typed into the code; without such a README no offset is added. Ranges <= 0 are impossible values (failed
ranging, not noisy measurements; the source's analysis discards them too) and are dropped and counted.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from harness.errors import InputFileNotFound
from harness.flight.formats.anchors import load_anchor_yaml
from harness.flight.formats.common import (CsvTable, RecordingError, anchor_positions, check_not_backwards,
                                           distinct_poses, normalised_quats, read_csv_table, repeated_rows,
                                           require_columns)
from harness.flight.data import KIND_TWR, Anchors, Flight, FlightError, Truth, UwbStream

POSITION_COLUMNS = tuple(f"Position {a}" for a in "XYZ")
ORIENTATION_COLUMNS = tuple(f"Orientation {a}" for a in "XYZW")     # quaternion x, y, z, w
#: the columns the readers use, looked up by name (a file may carry more; their order is the file's)
RANGE_COLUMNS = ("Time", "Address", "Range", *POSITION_COLUMNS, *ORIENTATION_COLUMNS)
GT_COLUMNS = ("Time", *POSITION_COLUMNS, *ORIENTATION_COLUMNS)
#: anchor_offset default: the antenna offset the data folder's README.md states (see readme_anchor_offset)
FROM_DATA_README = "readme"
_README_OFFSET = re.compile(r"adds\s*\(([^)]*)\)\s*m\s+to\s+the\s+anchor\s+positions", re.IGNORECASE)
_ANCHOR_FILE = re.compile(r"^anchor_(\d+)\.csv$")


def is_rcv_twr_dir(path: Path) -> bool:
    return path.is_dir() and ((path / "anchor.yaml").exists() or any(
        _ANCHOR_FILE.match(p.name) for p in path.iterdir()))


def readme_anchor_offset(directory: Path) -> np.ndarray:
    """The antenna offset [m] the data README states ("... adds (x, y, z) m to the anchor positions"), from
    README.md beside the sequence folder or one level up (../shared/data/README.md for rcv_twr/sequenceN);
    zero when neither README says so. A README that states it unreadably is a RecordingError."""
    for readme in (directory.parent / "README.md", directory.parent.parent / "README.md"):
        if not readme.is_file():
            continue
        found = _README_OFFSET.search(readme.read_text(encoding="utf-8", errors="replace"))
        if found is None:
            continue
        try:
            offset = np.array([float(v) for v in found.group(1).split(",")])
        except ValueError:
            offset = np.array([])
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise RecordingError(f"antenna offset ({found.group(1)}) is not three numbers [m]", path=readme)
        return offset
    return np.zeros(3)


def load_rcv_twr(directory: Path, anchors: Anchors | None = None,
                 anchor_offset: tuple[float, float, float] | str | None = FROM_DATA_README,
                 drop_nonpositive: bool = True) -> Flight:
    """One sequence directory -> Flight. `anchors` overrides anchor.yaml (the offset is applied to either);
    `anchor_offset`: FROM_DATA_README (the data README's), a vector [m], or None (no offset)."""
    directory = Path(directory)
    if not directory.exists():
        raise InputFileNotFound(f"recording {directory} not found")
    if anchors is None:
        yaml = directory / "anchor.yaml"
        if not yaml.exists():
            raise InputFileNotFound(f"anchor file {yaml} not found (an rcv_twr sequence needs anchor.yaml)")
        anchors = load_anchor_yaml(yaml)
    if anchor_offset == FROM_DATA_README:
        offset = readme_anchor_offset(directory)
    else:
        offset = np.zeros(3) if anchor_offset is None else np.asarray(anchor_offset, dtype=np.float64)
    anchors = Anchors(ids=anchors.ids, positions=anchors.positions + offset, orientations=anchors.orientations)
    gt, gt_t, tables = _read_tables(directory, set(int(i) for i in anchors.ids))
    t0 = min([int(gt_t[0])] + [int(t[0]) for _, _, t in tables if len(t)])
    dropped: dict[str, int] = {}
    addresses: dict[str, list[int]] = {}
    t, aid, rng, matched = _merged_ranges(tables, t0, drop_nonpositive, dropped, addresses)
    truth = _truth(gt, gt_t - t0, dropped)
    inside = (t >= truth.t_us[0]) & (t <= truth.t_us[-1])
    if (~inside).any():
        dropped["range_outside_truth_span"] = int((~inside).sum())
    t, aid, rng, matched = t[inside], aid[inside], rng[inside], matched[inside]
    if len(t) == 0:
        raise RecordingError("no range measurement falls within the ground truth's time span", path=directory)
    true_value = np.linalg.norm(matched - anchor_positions(anchors, aid), axis=1)
    uwb = UwbStream(kind=KIND_TWR, t_us=t, anchor_a=aid, anchor_b=np.full(len(t), -1, dtype=np.int64), value=rng,
                    true_value=true_value)
    meta: dict[str, object] = {
        "source": str(directory),
        "format": "rcv-twr",
        "dataset": "RCV_uwb_dataset",
        "t0_unix_us": int(t0),
        "anchor_offset_m": offset.tolist(),
        "anchor_addresses": addresses,
        "dropped": dropped,
    }
    flight = Flight(name=f"rcv_twr-{directory.name}", anchors=anchors, uwb=uwb, truth=truth, imu=None, meta=meta)
    try:
        flight.validate()
    except FlightError as exc:  # pragma: no cover - the checks above are stricter
        raise RecordingError(str(exc), path=directory) from None
    return flight


def _read_tables(directory: Path,
                 known: set[int]) -> tuple[CsvTable, np.ndarray, list[tuple[int, CsvTable, np.ndarray]]]:
    """The ground truth (with its absolute times) and every anchor_K.csv (anchor id, table, absolute times)."""
    files = sorted((int(m.group(1)), p) for p in directory.iterdir() if (m := _ANCHOR_FILE.match(p.name)))
    if not files:
        raise RecordingError("no anchor_K.csv range files in this directory", path=directory)
    gt_path = directory / "gt.csv"
    gt = read_csv_table(gt_path, "rcv_twr ground-truth CSV")
    require_columns(gt, GT_COLUMNS, "rcv_twr ground-truth CSV")
    if len(gt) < 2:
        raise RecordingError(f"the ground truth needs at least 2 samples, got {len(gt)}", path=gt_path)
    gt_t = _datetimes(gt)
    tables: list[tuple[int, CsvTable, np.ndarray]] = []
    for k, path in files:
        table = read_csv_table(path, "rcv_twr range CSV")
        require_columns(table, RANGE_COLUMNS, "rcv_twr range CSV")
        if k not in known:
            raise RecordingError(f"unknown anchor {k}: the anchor file has {sorted(known)}", path=path)
        tables.append((k, table, _datetimes(table)))
    return gt, gt_t, tables


def _merged_ranges(tables: list[tuple[int, CsvTable, np.ndarray]], t0: int, drop_nonpositive: bool,
                   dropped: dict[str, int], addresses: dict[str, list[int]]) -> tuple[np.ndarray, ...]:
    """Every anchor's ranges in one time-ordered stream: (t_us, anchor id, range, tag position), logging
    duplicates (and non-positive ranges) dropped and counted in `dropped`, the radio addresses seen per
    anchor in `addresses`."""
    parts = []
    for k, table, t_abs in tables:
        t = t_abs - t0
        check_not_backwards(t, table, "Time")
        rng = table.floats("Range")
        addr = table.ints("Address", hi=1 << 31)
        pose = np.stack([table.floats(c) for c in POSITION_COLUMNS], axis=1)
        rep = repeated_rows(t, rng, pose)
        if rep.any():
            dropped[f"duplicate_rows_anchor_{k}"] = int(rep.sum())
        keep = ~rep
        if drop_nonpositive:
            bad = keep & ~(rng > 0)
            if bad.any():
                dropped[f"nonpositive_range_anchor_{k}"] = int(bad.sum())
            keep &= rng > 0
        addresses[str(k)] = sorted(set(int(x) for x in addr))
        parts.append((t[keep], np.full(int(keep.sum()), k, dtype=np.int64), rng[keep], pose[keep]))
    t, aid, rng, matched = (np.concatenate([p[i] for p in parts]) for i in range(4))
    order = np.lexsort((aid, t))    # time order; equal times by anchor id, so the merge is deterministic
    return t[order], aid[order], rng[order], matched[order]


def _datetimes(table: CsvTable) -> np.ndarray:
    """`YYYY-MM-DD HH:MM:SS.ffffff` cells -> int64 microseconds since the Unix epoch (naive wall clock)."""
    cells = [c.strip() for c in table.column("Time")]
    try:
        return np.array(cells, dtype="datetime64[us]").astype(np.int64)
    except ValueError:
        for k, c in enumerate(cells):
            try:
                np.datetime64(c, "us")
                if not re.match(r"^\d{4}-\d\d-\d\d[ T]\d\d:\d\d:\d\d", c):
                    raise ValueError(c)
            except ValueError:
                raise RecordingError(f"expected a date-time 'YYYY-MM-DD HH:MM:SS.ffffff', got {c!r}",
                                     path=table.path, line=int(table.lines[k]), field="Time") from None
        raise  # pragma: no cover


def _truth(gt: CsvTable, t: np.ndarray, dropped: dict[str, int]) -> Truth:
    check_not_backwards(t, gt, "Time")
    pos = np.stack([gt.floats(c) for c in POSITION_COLUMNS], axis=1)
    q_xyzw = np.stack([gt.floats(c) for c in ORIENTATION_COLUMNS], axis=1)
    quat = normalised_quats(q_xyzw[:, [3, 0, 1, 2]], gt, "Orientation W")
    keep, n_rep = distinct_poses(t, gt, "Time", pos, quat)
    if n_rep:
        dropped["duplicate_gt_rows"] = n_rep
    return Truth(t_us=t[keep], pos=pos[keep], quat=quat[keep])
