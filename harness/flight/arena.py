"""The flight arena: bounds, anchor constellation (positions and antenna orientations), obstacles.

Default: the paper's 7 x 8 x 3 m arena centred on the origin (like the UTIL survey frame), 8 anchors at
the vertices of the volume (lower ring 0.15 m above the floor, upper ring 0.15 m below the ceiling), each
antenna's x axis pointing at the arena centre (the paper's Fig. 6: "each facing towards its own x-axis").
Anchor ids follow UTIL constellation 1's pattern, alternating low/high around the arena, so the TDoA2
consecutive pairs (7,0),(0,1),...,(6,7) always span a height difference.

Constellations load from a CSV `constellation,anchor_id,x_m,y_m,z_m` (UTIL `anchors.csv`) or a small YAML
file (see `load_constellation`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.flight.formats.yaml_lines import LineList, LineMap, YamlSyntaxError, load_yaml_lines
from harness.flight.data import Anchors, FlightError
from harness.flight.trajectory import rot_to_quat


class ConstellationError(FlightError):
    """A constellation file is missing or malformed (the message names the file and line)."""


@dataclass(frozen=True)
class Box:
    """Axis-aligned obstacle [m]."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]

    def segment_hits(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """(N,) bool: does the segment p0[i] -> p1[i] cross this box? (slab test)"""
        lo = np.asarray(self.lo)
        hi = np.asarray(self.hi)
        d = p1 - p0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (lo[None, :] - p0) * inv
            t2 = (hi[None, :] - p0) * inv
        tmin = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
        tmax = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2))
        # a zero direction component: inside the slab -> no constraint, outside -> miss
        zero = d == 0.0
        inside = (p0 >= lo[None, :]) & (p0 <= hi[None, :])
        tmin = np.where(zero, np.where(inside, -np.inf, np.inf), tmin)
        tmax = np.where(zero, np.where(inside, np.inf, -np.inf), tmax)
        enter = np.max(tmin, axis=1)
        leave = np.min(tmax, axis=1)
        return (enter <= leave) & (leave >= 0.0) & (enter <= 1.0)


@dataclass(frozen=True)
class Arena:
    lo: tuple[float, float, float] = (-3.5, -4.0, 0.0)
    hi: tuple[float, float, float] = (3.5, 4.0, 3.0)
    anchors: Anchors = field(default_factory=lambda: default_anchors())
    boxes: tuple[Box, ...] = ()

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.lo) + np.asarray(self.hi))

    def blocked(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """(N,) bool: the straight line p0[i] -> p1[i] crosses an obstacle."""
        out = np.zeros(p0.shape[0], dtype=bool)
        for b in self.boxes:
            out |= b.segment_hits(p0, p1)
        return out


# Constellation 1 of UTIL, idealised to the vertices: (x sign, y sign, high?) per anchor id.
_VERTEX_PATTERN = ((-1, -1, 0), (-1, 1, 1), (1, 1, 0), (1, -1, 1), (-1, -1, 1), (1, -1, 0), (1, 1, 1), (-1, 1, 0))

# Obstacles of the "nlos" profile: two boxes standing on the floor inside the arena (like UTIL const3's
# cardboard/metal obstacles between the flight volume and some anchors).
NLOS_BOXES = (Box((-2.6, -1.0, 0.0), (-1.8, 1.0, 1.6)), Box((1.6, -3.2, 0.0), (2.6, -2.2, 2.0)),
              Box((1.0, 2.2, 0.0), (2.2, 3.0, 1.2)))


def facing(positions: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Orientations (N, 4) whose x axis points from each position to `target`, z axis as close to world up
    as that allows."""
    x = np.asarray(target)[None, :] - positions
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    y = np.cross(up[None, :], x)
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    z = np.cross(x, y)
    return rot_to_quat(np.stack([x, y, z], axis=2))


def default_anchors(lo: tuple[float, float, float] = (-3.5, -4.0, 0.0),
                    hi: tuple[float, float, float] = (3.5, 4.0, 3.0), inset_z: float = 0.15) -> Anchors:
    pos = []
    for sx, sy, high in _VERTEX_PATTERN:
        x = hi[0] if sx > 0 else lo[0]
        y = hi[1] if sy > 0 else lo[1]
        z = hi[2] - inset_z if high else lo[2] + inset_z
        pos.append((x, y, z))
    p = np.array(pos, dtype=np.float64)
    center = 0.5 * (np.asarray(lo) + np.asarray(hi))
    return Anchors(ids=np.arange(8), positions=p, orientations=facing(p, center))


def with_facing_orientations(anchors: Anchors, center: np.ndarray) -> Anchors:
    """Give a constellation without orientations (UTIL surveys have none) antennas facing `center`."""
    if anchors.orientations is not None:
        return anchors
    return Anchors(ids=anchors.ids, positions=anchors.positions, orientations=facing(anchors.positions, center))


# ------------------------------------------------------------------------------------------ files
def load_constellation(path: Path | str, constellation: int | None = None) -> Anchors:
    """Anchors from a CSV (`constellation,anchor_id,x_m,y_m,z_m`; `constellation` picks one, required when
    the file holds several) or a YAML file of the form

        anchors:
          - {id: 0, position: [x, y, z], orientation: [w, x, y, z]}   # orientation optional

    Anchors without orientation get antennas facing the constellation's centroid."""
    path = Path(path)
    if not path.is_file():
        raise ConstellationError(f"{path}: constellation file not found")
    if path.suffix.lower() in (".yaml", ".yml"):
        anchors = _load_yaml(path)
    else:
        anchors = _load_csv(path, constellation)
    return with_facing_orientations(anchors, anchors.positions.mean(axis=0))


def _load_csv(path: Path, constellation: int | None) -> Anchors:
    rows: dict[int, list[tuple[int, float, float, float]]] = {}
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        want = ["constellation", "anchor_id", "x_m", "y_m", "z_m"]
        if header is None or [h.strip() for h in header] != want:
            raise ConstellationError(f"{path}:1: expected header {','.join(want)}, got {header!r}")
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != 5:
                raise ConstellationError(f"{path}:{lineno}: expected 5 fields, got {len(row)}")
            try:
                c, a = int(row[0]), int(row[1])
            except ValueError:
                raise ConstellationError(f"{path}:{lineno}: constellation and anchor_id must be integers, "
                                         f"got {row[0]!r}, {row[1]!r}") from None
            xyz = []
            for name, cell in zip(want[2:], row[2:]):
                try:
                    v = float(cell)
                except ValueError:
                    raise ConstellationError(f"{path}:{lineno}: field {name} is not a number: {cell!r}") from None
                if not math.isfinite(v):
                    raise ConstellationError(f"{path}:{lineno}: field {name} is not finite: {cell!r}")
                xyz.append(v)
            rows.setdefault(c, []).append((a, xyz[0], xyz[1], xyz[2]))
    if not rows:
        raise ConstellationError(f"{path}: no anchors")
    if constellation is None:
        if len(rows) > 1:
            raise ConstellationError(f"{path}: holds constellations {sorted(rows)}; say which one")
        constellation = next(iter(rows))
    if constellation not in rows:
        raise ConstellationError(f"{path}: no constellation {constellation} (has {sorted(rows)})")
    sel = sorted(rows[constellation])
    ids = np.array([r[0] for r in sel], dtype=np.int64)
    if len(set(ids.tolist())) != len(ids):
        raise ConstellationError(f"{path}: constellation {constellation} repeats an anchor id")
    return Anchors(ids=ids, positions=np.array([r[1:] for r in sel], dtype=np.float64))


def _numbers(value: object, path: Path, lineno: int, field_name: str, n: int) -> list[float]:
    ok = isinstance(value, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    if not ok:
        raise ConstellationError(f"{path}:{lineno}: field {field_name} must be a list of {n} numbers, got {value!r}")
    vals = [float(v) for v in value]  # type: ignore[union-attr]
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ConstellationError(f"{path}:{lineno}: field {field_name} needs {n} finite numbers, got {value!r}")
    return vals


def _load_yaml(path: Path) -> Anchors:
    """`anchors:` - a list of {id, position, orientation (optional)} in any YAML style (PyYAML); the loaded
    data is validated entry by entry with the file line of each value."""
    try:
        doc = load_yaml_lines(path)
    except YamlSyntaxError as exc:
        raise ConstellationError(f"{path}:{exc.line or 1}: {exc}") from None
    if not isinstance(doc, LineMap) or "anchors" not in doc:
        raise ConstellationError(f"{path}:{getattr(doc, 'line', 1)}: expected a mapping with key 'anchors:' "
                                 "(a list of {id: N, position: [x, y, z]})")
    extra = sorted(str(k) for k in doc if k != "anchors")
    if extra:
        raise ConstellationError(f"{path}:{doc.line_of(extra[0])}: unexpected key {extra[0]!r} (only 'anchors')")
    entries = doc["anchors"]
    if not isinstance(entries, LineList) or not entries:
        raise ConstellationError(f"{path}:{doc.line_of('anchors')}: no anchors (expected a list under 'anchors:')")
    ids: list[int] = []
    pos: list[list[float]] = []
    ori: list[list[float] | None] = []
    for k, e in enumerate(entries):
        line = entries.line_of(k)
        if not isinstance(e, LineMap) or "id" not in e or "position" not in e:
            raise ConstellationError(f"{path}:{line}: an anchor needs id and position, got {e!r}")
        unknown = sorted(str(x) for x in e if x not in ("id", "position", "orientation"))
        if unknown:
            raise ConstellationError(f"{path}:{e.line_of(unknown[0])}: unknown field {unknown[0]!r}")
        if not isinstance(e["id"], int) or isinstance(e["id"], bool):
            raise ConstellationError(f"{path}:{e.line_of('id')}: field id must be an integer, got {e['id']!r}")
        ids.append(int(e["id"]))
        pos.append(_numbers(e["position"], path, e.line_of("position"), "position", 3))
        ori.append(_numbers(e["orientation"], path, e.line_of("orientation"), "orientation", 4)
                   if "orientation" in e else None)
    if len(set(ids)) != len(ids):
        raise ConstellationError(f"{path}: repeated anchor id")
    orientations = None
    if all(o is not None for o in ori):
        q = np.array(ori, dtype=np.float64)
        if np.any(np.linalg.norm(q, axis=1) < 1e-9):
            raise ConstellationError(f"{path}: an orientation quaternion is zero")
        orientations = q / np.linalg.norm(q, axis=1, keepdims=True)
    return Anchors(ids=np.array(ids, dtype=np.int64), positions=np.array(pos, dtype=np.float64),
                   orientations=orientations)

