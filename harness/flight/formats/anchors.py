"""Anchor files of the recorded datasets -> `Anchors`.

* `anchors.csv` (this project's extract of the UTIL surveys): `constellation,anchor_id,x_m,y_m,z_m`;
  also accepted without the constellation column (one constellation per file).
* UTIL survey results `anchor_constN.npz`: arrays `an_pos` (N, 3) [m] and `an_quat` (N, 4) ordered
  (x, y, z, w), anchor body -> world; anchor id = row index.
* UTIL survey results `anchor_constN.txt` / `_survey.txt`: lines `anK_p,x,y,z` and `anK_quat,qx,qy,qz,qw`.
* rcv_twr `anchor.yaml`: `anchorK:` blocks with `- position: data: [x, y, z]` and
  `- orientation: data: [x, y, z, w]`; anchor id = K.

Orientations are stored (w, x, y, z), the project's convention; files that have none give None
(we do not invent antenna orientations for real data).
"""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from harness.errors import InputFileNotFound
from harness.flight.formats.common import RecordingError, normalised_quats, read_csv_table
from harness.flight.formats.yaml_lines import LineList, LineMap, YamlSyntaxError, load_yaml_lines
from harness.flight.data import Anchors, FlightError

ANCHORS_CSV_COLUMNS = ("constellation", "anchor_id", "x_m", "y_m", "z_m")
MAX_ANCHOR_ID = 255  # 8-bit ids (LPS anchors: low byte of the MAC address)
MAX_ANCHORS = 16     # the firmware's anchor table (ESTIMATOR_MAX_ANCHORS slots, keyed by id)
#: an anchor file holds a few lines: a larger file is not one (and would be read whole)
MAX_ANCHOR_FILE_BYTES = 1 << 20


def load_anchors(path: Path | str, constellation: int | None = None) -> Anchors:
    """Anchors from any supported anchor file (chosen by extension). `constellation` selects one
    constellation of a multi-constellation CSV."""
    path = Path(path)
    if not path.exists():
        raise InputFileNotFound(f"anchor file {path} not found")
    if path.is_file() and path.stat().st_size > MAX_ANCHOR_FILE_BYTES:
        raise RecordingError(f"{path.stat().st_size} bytes: too large for an anchor file (at most "
                             f"{MAX_ANCHOR_FILE_BYTES})", path=path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return load_anchors_csv(path, constellation)
    if suffix == ".npz":
        return load_survey_npz(path)
    if suffix == ".txt":
        return load_survey_txt(path)
    if suffix in (".yaml", ".yml"):
        return load_anchor_yaml(path)
    raise RecordingError("unknown anchor file type: expected .csv (anchors.csv), .npz / .txt (UTIL survey) "
                         "or .yaml (rcv_twr anchor.yaml)", path=path)


def _make_anchors(ids: np.ndarray, pos: np.ndarray, quat: np.ndarray | None, path: Path) -> Anchors:
    bad = [int(i) for i in ids if not 0 <= int(i) <= MAX_ANCHOR_ID]
    if bad:
        raise RecordingError(f"anchor id(s) {bad} outside 0..{MAX_ANCHOR_ID} (8-bit anchor ids)", path=path)
    if len(np.unique(ids)) > MAX_ANCHORS:
        raise RecordingError(f"{len(np.unique(ids))} anchors: the firmware's anchor table holds {MAX_ANCHORS}",
                             path=path)
    try:
        return Anchors(ids=np.asarray(ids, dtype=np.int64), positions=np.asarray(pos, dtype=np.float64),
                       orientations=quat)
    except FlightError as exc:
        raise RecordingError(str(exc), path=path) from None


# -------------------------------------------------------------------------------------- anchors.csv
def load_anchors_csv(path: Path, constellation: int | None = None) -> Anchors:
    table = read_csv_table(path, "anchor CSV")
    has_const = "constellation" in table.header
    needed = ANCHORS_CSV_COLUMNS if has_const else ANCHORS_CSV_COLUMNS[1:]
    missing = [c for c in needed if c not in table.header]
    if missing:
        raise RecordingError(f"not an anchor CSV: missing column(s) {missing}; expected header "
                             f"{','.join(ANCHORS_CSV_COLUMNS)}", path=path, line=1)
    if len(table) == 0:
        raise RecordingError("no anchors (header only)", path=path)
    ids = table.ints("anchor_id", hi=MAX_ANCHOR_ID)
    pos = np.stack([table.floats(c) for c in ("x_m", "y_m", "z_m")], axis=1)
    if not has_const:
        # one constellation per file: it is whichever the recording names (constN), so no selection
        constellation = None
    const = table.ints("constellation", hi=1 << 30) if has_const else np.zeros(len(table), dtype=np.int64)
    available = sorted(set(int(c) for c in const))
    if constellation is None:
        if len(available) > 1:
            raise RecordingError(f"holds constellations {available}; say which one (the recording's file name "
                                 "names it as constN, or pass --constellation N)", path=path)
        constellation = available[0]
    if constellation not in available:
        raise RecordingError(f"no constellation {constellation} in this file (it has {available})", path=path,
                             field="constellation")
    sel = np.nonzero(const == constellation)[0]
    seen: dict[int, int] = {}
    for k in sel:
        a = int(ids[k])
        if a in seen:
            raise RecordingError(f"anchor {a} of constellation {constellation} repeats line {seen[a]}",
                                 path=path, line=int(table.lines[k]), field="anchor_id")
        seen[a] = int(table.lines[k])
    order = sel[np.argsort(ids[sel], kind="stable")]
    return _make_anchors(ids[order], pos[order], None, path)


# ------------------------------------------------------------------------------------ UTIL surveys
def load_survey_npz(path: Path) -> Anchors:
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            if not {"an_pos", "an_quat"} <= keys:
                raise RecordingError(f"not a UTIL survey file: expected arrays an_pos and an_quat, found "
                                     f"{sorted(keys)}", path=path)
            pos = np.asarray(z["an_pos"], dtype=np.float64)
            quat_xyzw = np.asarray(z["an_quat"], dtype=np.float64)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        if isinstance(exc, RecordingError):
            raise
        raise RecordingError(f"not a readable .npz file ({exc})", path=path) from None
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise RecordingError(f"an_pos must be (N, 3), got {pos.shape}", path=path, field="an_pos")
    if quat_xyzw.shape != (len(pos), 4):
        raise RecordingError(f"an_quat must be ({len(pos)}, 4), got {quat_xyzw.shape}", path=path,
                             field="an_quat")
    for name, arr in (("an_pos", pos), ("an_quat", quat_xyzw)):
        if not np.all(np.isfinite(arr)):
            raise RecordingError("non-finite values", path=path, field=name)
    quat = normalised_quats(quat_xyzw[:, [3, 0, 1, 2]], None, "an_quat", path=path)
    return _make_anchors(np.arange(len(pos)), pos, quat, path)


_TXT_LINE = re.compile(r"^an(\d+)_(p|quat)$")


def load_survey_txt(path: Path) -> Anchors:
    if not path.is_file():
        raise RecordingError("expected a survey text file", path=path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise RecordingError("not a UTF-8 text file", path=path) from None
    pos: dict[int, list[float]] = {}
    quat: dict[int, list[float]] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        cells = [c.strip() for c in raw.split(",")]
        m = _TXT_LINE.match(cells[0])
        if m is None:
            raise RecordingError(f"expected 'anK_p,x,y,z' or 'anK_quat,qx,qy,qz,qw', got {cells[0]!r}",
                                 path=path, line=lineno)
        aid, kind = int(m.group(1)), m.group(2)
        n = 3 if kind == "p" else 4
        if len(cells) != n + 1:
            raise RecordingError(f"expected {n} numbers after {cells[0]}, got {len(cells) - 1}", path=path,
                                 line=lineno)
        try:
            vals = [float(c) for c in cells[1:]]
        except ValueError:
            raise RecordingError(f"expected numbers, got {cells[1:]}", path=path, line=lineno,
                                 field=cells[0]) from None
        if not all(np.isfinite(vals)):
            raise RecordingError(f"expected finite numbers, got {cells[1:]}", path=path, line=lineno,
                                 field=cells[0])
        target = pos if kind == "p" else quat
        if aid in target:
            raise RecordingError(f"{cells[0]} given twice", path=path, line=lineno, field=cells[0])
        target[aid] = vals
    if not pos:
        raise RecordingError("no anchor positions (anK_p lines)", path=path)
    if quat and set(quat) != set(pos):
        raise RecordingError(f"anchors with a position {sorted(pos)} and with a quaternion {sorted(quat)} "
                             "differ", path=path)
    ids = np.array(sorted(pos), dtype=np.int64)
    p = np.array([pos[int(i)] for i in ids])
    q = None
    if quat:
        q = normalised_quats(np.array([quat[int(i)] for i in ids])[:, [3, 0, 1, 2]], None, "anK_quat", path=path)
    return _make_anchors(ids, p, q, path)


# ------------------------------------------------------------------------------ rcv_twr anchor.yaml
_YAML_ANCHOR_KEY = re.compile(r"anchor(\d+)")
_YAML_ITEMS = {"position": 3, "orientation": 4}


def load_anchor_yaml(path: Path) -> Anchors:
    """The rcv_twr anchor.yaml, read with PyYAML (block or flow style): `anchorK:` entries holding a
    `position` (3 numbers) and optionally an `orientation` (x, y, z, w), each either a list of one-key
    mappings (`- position: {data: [..]}`, the dataset's own shape) or a mapping, the numbers either under
    `data:` or given directly. A project constellation YAML (`anchors:` list) goes to the arena's reader."""
    if not path.is_file():
        raise RecordingError("expected an anchor YAML file", path=path)
    try:
        doc = load_yaml_lines(path)
    except YamlSyntaxError as exc:
        raise RecordingError(str(exc), path=path, line=exc.line) from None
    if isinstance(doc, LineMap) and "anchors" in doc:
        from harness.flight.arena import load_constellation  # the simulator's constellation format
        return load_constellation(path)
    if not isinstance(doc, LineMap) or not doc:
        raise RecordingError("no anchors (expected anchorK: entries with a position)", path=path,
                             line=getattr(doc, "line", None))
    pos: dict[int, list[float]] = {}
    quat: dict[int, list[float]] = {}
    for key, value in doc.items():
        m = _YAML_ANCHOR_KEY.fullmatch(str(key))
        if m is None:
            raise RecordingError(f"unexpected key {key!r}: expected anchorK (K = the anchor id) or anchors:",
                                 path=path, line=doc.line_of(key))
        k = int(m.group(1))
        for item, (val, line) in _anchor_items(value, path, doc.line_of(key), str(key)).items():
            (pos if item == "position" else quat)[k] = _yaml_numbers(val, _YAML_ITEMS[item], path, line,
                                                                   f"{key}.{item}")
        if k not in pos:
            raise RecordingError("anchor has no position", path=path, line=doc.line_of(key), field=str(key))
    ids = np.array(sorted(pos), dtype=np.int64)
    q = None
    if quat:
        if set(quat) != set(pos):
            raise RecordingError(f"anchor(s) {sorted(set(pos) - set(quat))} have no orientation", path=path)
        q = normalised_quats(np.array([quat[int(i)] for i in ids])[:, [3, 0, 1, 2]], None, "orientation",
                             path=path)
    return _make_anchors(ids, np.array([pos[int(i)] for i in ids]), q, path)


def _anchor_items(value: object, path: Path, line: int, name: str) -> dict[str, tuple[object, int]]:
    """{"position" | "orientation": (value, line)} of one anchorK entry (a list of one-key maps or a map)."""
    entries: list[tuple[object, object, int]] = []
    if isinstance(value, LineMap):
        entries = [(k, v, value.line_of(k)) for k, v in value.items()]
    elif isinstance(value, LineList):
        for i, it in enumerate(value):
            if not isinstance(it, LineMap):
                raise RecordingError("expected '- position: ...' or '- orientation: ...'", path=path,
                                     line=value.line_of(i), field=name)
            entries += [(k, v, it.line_of(k)) for k, v in it.items()]
    else:
        raise RecordingError("expected a position (and orientation) under the anchor", path=path, line=line,
                             field=name)
    out: dict[str, tuple[object, int]] = {}
    for k, v, ln in entries:
        if k not in _YAML_ITEMS:
            raise RecordingError(f"unexpected key {k!r}: expected position or orientation", path=path, line=ln,
                                 field=name)
        if k in out:
            raise RecordingError(f"{k} given twice", path=path, line=ln, field=name)
        if isinstance(v, LineMap):       # the dataset's `data: [..]` wrapper
            if set(v) != {"data"}:
                raise RecordingError(f"expected 'data: [..]' under {k}, got keys {sorted(map(str, v))}",
                                     path=path, line=ln, field=f"{name}.{k}")
            v, ln = v["data"], v.line_of("data")
        out[str(k)] = (v, ln)
    return out


def _yaml_numbers(value: object, n: int, path: Path, line: int, field: str) -> list[float]:
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    if not ok:
        raise RecordingError(f"expected {n} numbers in [..], got {value!r}", path=path, line=line, field=field)
    vals = [float(v) for v in value]  # type: ignore[union-attr]
    if not all(np.isfinite(vals)):
        raise RecordingError(f"expected {n} finite numbers, got {value!r}", path=path, line=line, field=field)
    return vals
