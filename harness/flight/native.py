"""The native recording format: one compressed .npz holding every array of a Flight plus a JSON header.

Members (all plain numpy arrays; the file loads with allow_pickle=False):

    flight_json          0-d unicode string: {"format": "uwb-hil-flight", "version": 1, "name": ...,
                         "uwb_kind": 1|2, "meta": {...}}
    anchors_ids          (N,)   anchors_positions (N, 3)   [anchors_orientations (N, 4) w,x,y,z]
    uwb_t_us (M,) int64  uwb_anchor_a (M,)  uwb_anchor_b (M,)  uwb_value (M,)  [uwb_true_value (M,)]
    truth_t_us (K,)      truth_pos (K, 3)   [truth_quat (K, 4)]  [truth_vel (K, 3)]
    [imu_t_us (L,)  imu_acc (L, 3)  imu_gyro (L, 3)]

Optional members are absent when the Flight field is None. Arrays keep their dtype and bytes, so
`load_flight(save_flight(f, p))` reproduces every array bit for bit. `meta` must be JSON: numpy scalars
are stored as Python numbers, numpy arrays and tuples come back as lists.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from harness.errors import InputFileNotFound
from harness.flight.formats.common import RecordingError
from harness.flight.data import Anchors, Flight, FlightError, ImuStream, Truth, UwbStream
from harness.kinds import KINDS

FORMAT_NAME = "uwb-hil-flight"
FORMAT_VERSION = 1
HEADER_KEY = "flight_json"

# member -> (owner attribute path, required)
_MEMBERS: dict[str, tuple[str, bool]] = {
    "anchors_ids": ("anchors.ids", True),
    "anchors_positions": ("anchors.positions", True),
    "anchors_orientations": ("anchors.orientations", False),
    "uwb_t_us": ("uwb.t_us", True),
    "uwb_anchor_a": ("uwb.anchor_a", True),
    "uwb_anchor_b": ("uwb.anchor_b", True),
    "uwb_value": ("uwb.value", True),
    "uwb_true_value": ("uwb.true_value", False),
    "truth_t_us": ("truth.t_us", True),
    "truth_pos": ("truth.pos", True),
    "truth_quat": ("truth.quat", False),
    "truth_vel": ("truth.vel", False),
    "imu_t_us": ("imu.t_us", False),
    "imu_acc": ("imu.acc", False),
    "imu_gyro": ("imu.gyro", False),
}


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"meta value of type {type(obj).__name__} is not JSON-serialisable")


def save_flight(flight: Flight, path: Path | str) -> Path:
    """Write the flight to `path` (written to a temporary file, then renamed: no half-written recordings)."""
    path = Path(path)
    try:
        flight.validate()
    except FlightError as exc:
        raise RecordingError(f"refusing to save an invalid flight: {exc}", path=path) from None
    try:
        header = json.dumps({"format": FORMAT_NAME, "version": FORMAT_VERSION, "name": flight.name,
                             "uwb_kind": int(flight.uwb.kind), "meta": flight.meta}, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"flight.meta cannot be stored: {exc}", path=path, field="meta") from None
    arrays: dict[str, np.ndarray] = {HEADER_KEY: np.array(header)}
    for member, (attr, _) in _MEMBERS.items():
        owner_name, field = attr.split(".")
        owner = getattr(flight, owner_name)
        value = getattr(owner, field) if owner is not None else None
        if value is not None:
            arrays[member] = np.asarray(value)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def is_native(path: Path) -> bool:
    """True if the .npz file has the native header member."""
    try:
        with zipfile.ZipFile(path) as z:
            return f"{HEADER_KEY}.npy" in z.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


def _known_kind(kind: object, path: Path) -> int:
    """The header's uwb_kind: a kind of harness/kinds.py."""
    if not isinstance(kind, int) or kind not in KINDS:
        known = " or ".join(f"{k.code} ({k.label})" for k in KINDS.values())
        raise RecordingError(f"uwb_kind must be {known}, got {kind!r}", path=path, field="uwb_kind")
    return kind


def load_flight(path: Path | str) -> Flight:
    """Read a native recording; every malformation is a RecordingError naming the file and the member."""
    path = Path(path)
    data = _read_members(path)
    try:
        header = json.loads(str(data[HEADER_KEY]))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"header is not valid JSON ({exc})", path=path, field=HEADER_KEY) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        raise RecordingError(f"header format must be {FORMAT_NAME!r}", path=path, field=HEADER_KEY)
    version = header.get("version")
    if version != FORMAT_VERSION:
        raise RecordingError(f"unsupported format version {version!r} (this harness reads version "
                             f"{FORMAT_VERSION})", path=path, field="version")
    kind = _known_kind(header.get("uwb_kind"), path)
    if not isinstance(header.get("meta", {}), dict):
        raise RecordingError("meta must be a JSON object", path=path, field="meta")
    unknown = sorted(set(data) - set(_MEMBERS) - {HEADER_KEY})
    if unknown:
        raise RecordingError(f"unknown member(s) {unknown}", path=path)
    for member, (_, required) in _MEMBERS.items():
        if required and member not in data:
            raise RecordingError("required member missing", path=path, field=member)
    for member in ("uwb_t_us", "truth_t_us", "imu_t_us"):
        if member in data and data[member].dtype != np.int64:
            raise RecordingError(f"timestamps must be int64 microseconds, got {data[member].dtype}", path=path,
                                 field=member)
    imu_members = [m for m in ("imu_t_us", "imu_acc", "imu_gyro") if m in data]
    if imu_members and len(imu_members) != 3:
        raise RecordingError(f"IMU needs imu_t_us, imu_acc and imu_gyro together, found {imu_members}", path=path)
    for member, arr in data.items():
        if member != HEADER_KEY and arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise RecordingError("non-finite values", path=path, field=member)
    for member in ("anchors_ids", "uwb_anchor_a", "uwb_anchor_b"):
        _check_integral(data, member, path)
    try:
        anchors = Anchors(ids=data["anchors_ids"], positions=data["anchors_positions"],
                          orientations=data.get("anchors_orientations"))
        uwb = UwbStream(kind=int(kind), t_us=data["uwb_t_us"], anchor_a=data["uwb_anchor_a"],
                        anchor_b=data["uwb_anchor_b"], value=data["uwb_value"], true_value=data.get("uwb_true_value"))
        truth = Truth(t_us=data["truth_t_us"], pos=data["truth_pos"], quat=data.get("truth_quat"),
                      vel=data.get("truth_vel"))
        imu = ImuStream(t_us=data["imu_t_us"], acc=data["imu_acc"], gyro=data["imu_gyro"]) if imu_members else None
        _check_shapes(uwb, truth, imu, anchors)
        flight = Flight(name=str(header.get("name", path.stem)), anchors=anchors, uwb=uwb, truth=truth, imu=imu,
                        meta=dict(header.get("meta") or {}))
        flight.validate()
    except FlightError as exc:
        raise RecordingError(str(exc), path=path) from None
    return flight


def _read_members(path: Path) -> dict[str, np.ndarray]:
    """The .npz file's members by name, the native header among them."""
    if not path.exists():
        raise InputFileNotFound(f"recording {path} not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise RecordingError(f"not a readable .npz file ({exc})", path=path) from None
    if HEADER_KEY not in data:
        raise RecordingError(f"not a native uwb-hil recording: no {HEADER_KEY} member (has {sorted(data)})",
                             path=path)
    for name, arr in data.items():      # text where numbers belong failed deep in a float conversion (exit 4)
        if name != HEADER_KEY and arr.dtype.kind not in "biuf":
            raise RecordingError(f"expected numbers, got dtype {arr.dtype}", path=path, field=name)
    return data


def _check_integral(data: dict[str, np.ndarray], member: str, path: Path) -> None:
    """Anchor ids are integers: a float id that is not integral (5.9) would be truncated to another anchor."""
    arr = data.get(member)
    if arr is None or arr.dtype.kind in "iu":
        return
    if arr.dtype.kind != "f":
        raise RecordingError(f"expected integer anchor ids, got dtype {arr.dtype}", path=path, field=member)
    bad = np.nonzero(arr != np.round(arr))[0]
    if bad.size:
        raise RecordingError(f"expected integer anchor ids, got {float(arr.flat[bad[0]]):g} at index {int(bad[0])} "
                             f"({bad.size} non-integral)", path=path, field=member)
    data[member] = arr.astype(np.int64)


def _check_shapes(uwb: UwbStream, truth: Truth, imu: ImuStream | None, anchors: Anchors) -> None:
    for name, t in (("uwb_t_us", uwb.t_us), ("truth_t_us", truth.t_us)) + ((("imu_t_us", imu.t_us),) if imu is not None else ()):
        if t.ndim != 1:
            raise FlightError(f"{name} must be one-dimensional, got shape {t.shape}")
    m = len(uwb.t_us)
    if uwb.true_value is not None and uwb.true_value.shape != (m,):
        raise FlightError(f"uwb_true_value must have shape ({m},), got {uwb.true_value.shape}")
    k = len(truth.t_us)
    if truth.pos.shape != (k, 3):
        raise FlightError(f"truth_pos must have shape ({k}, 3), got {truth.pos.shape}")
    for name, arr, width in (("truth_quat", truth.quat, 4), ("truth_vel", truth.vel, 3)):
        if arr is not None and arr.shape != (k, width):
            raise FlightError(f"{name} must have shape ({k}, {width}), got {arr.shape}")
    if k and np.any(np.diff(truth.t_us) <= 0):
        raise FlightError("truth_t_us must be strictly increasing")
    if anchors.orientations is not None and anchors.orientations.shape != (len(anchors.ids), 4):
        raise FlightError(f"anchors_orientations must have shape ({len(anchors.ids)}, 4)")
    if imu is not None:
        n = len(imu.t_us)
        for name, arr in (("imu_acc", imu.acc), ("imu_gyro", imu.gyro)):
            if arr.shape != (n, 3):
                raise FlightError(f"{name} must have shape ({n}, 3), got {arr.shape}")
