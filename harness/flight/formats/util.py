"""UTIL dataset flight CSVs (Zhao et al., IJRR 2024) -> Flight (KIND_TDOA).

Two layouts, told apart by the header (column order does not matter, names do):

* official, 27 columns (the dataset's `csv-data/constN/*.csv`, written by its `log_to_csv.py`):
  `t_tdoa,idA,idB,tdoa_meas, t_acc,acc_x,acc_y,acc_z, t_gyro,gyro_x,gyro_y,gyro_z, t_tof,tof,
  t_flow,deltaX,deltaY, t_baro,baro, t_pose,pose_x,pose_y,pose_z,pose_qx,pose_qy,pose_qz,pose_qw`;
  every sensor is its own stream, shorter streams end in empty cells. Times [s], acc [g], gyro [deg/s],
  Vicon pose of the vehicle body (quaternion x, y, z, w; body -> world).
* reduced, 8 columns (`../shared/data/util/*-extracted.csv`): `idA,idB,tdoa_meas,t_tdoa,pose_x,pose_y,
  pose_z,t_pose`: the TDoA stream and the Vicon position stream, no attitude, no IMU.

`tdoa_meas` = d(tag, idB) - d(tag, idA), the UwbStream convention, so anchor_a = idA, anchor_b = idB.
Ground truth is the UWB tag: the Vicon body position plus the tag lever arm [-0.01245, 0.00127, 0.0908] m
(body frame). With a quaternion we rotate it; the reduced file has none, so we assume the vehicle is level
and add only the vertical 0.0908 m (the horizontal 1.3 cm cannot be placed without the yaw).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from harness.flight.formats.common import (CsvTable, RecordingError, anchor_positions, check_not_backwards,
                                           distinct_poses, imu_on_gyro_times, normalised_quats, quat_to_rotmat,
                                           read_csv_table, repeated_rows, seconds_to_us)
from harness.flight.data import KIND_TDOA, Anchors, Flight, FlightError, ImuStream, Truth, UwbStream

REDUCED_COLUMNS = ("idA", "idB", "tdoa_meas", "t_tdoa", "pose_x", "pose_y", "pose_z", "t_pose")
OFFICIAL_COLUMNS = ("t_tdoa", "idA", "idB", "tdoa_meas", "t_acc", "acc_x", "acc_y", "acc_z",
                    "t_gyro", "gyro_x", "gyro_y", "gyro_z", "t_tof", "tof", "t_flow", "deltaX", "deltaY",
                    "t_baro", "baro", "t_pose", "pose_x", "pose_y", "pose_z", "pose_qx", "pose_qy", "pose_qz",
                    "pose_qw")
TAG_LEVER_ARM = np.array([-0.01245, 0.00127, 0.0908])   # body frame, vehicle centre -> UWB tag [m]
GRAVITY = 9.81           # g -> m/s^2; the dataset's scripts and the firmware (EKF_GRAVITY) use this value
DEG = np.pi / 180.0

TDOA_STREAM = ("t_tdoa", "idA", "idB", "tdoa_meas")
POSE_STREAM_REDUCED = ("t_pose", "pose_x", "pose_y", "pose_z")
POSE_STREAM_OFFICIAL = POSE_STREAM_REDUCED + ("pose_qx", "pose_qy", "pose_qz", "pose_qw")
ACC_STREAM = ("t_acc", "acc_x", "acc_y", "acc_z")
GYRO_STREAM = ("t_gyro", "gyro_x", "gyro_y", "gyro_z")
OTHER_STREAMS = (("t_tof", "tof"), ("t_flow", "deltaX", "deltaY"), ("t_baro", "baro"))


def util_layout(header: tuple[str, ...]) -> str | None:
    """'reduced', 'official' or None for a header."""
    if set(header) == set(REDUCED_COLUMNS):
        return "reduced"
    if set(header) == set(OFFICIAL_COLUMNS):
        return "official"
    return None


def constellation_from_name(path: Path) -> int | None:
    m = re.search(r"const(\d+)", Path(path).name)
    return int(m.group(1)) if m else None


def load_util_csv(path: Path, anchors: Anchors) -> Flight:
    """A UTIL flight CSV (either layout) with its constellation's anchors."""
    table = read_csv_table(Path(path), "UTIL flight CSV")
    layout = util_layout(table.header)
    if layout is None:
        raise RecordingError(f"not a UTIL flight CSV: expected the 8-column header {','.join(REDUCED_COLUMNS)} "
                             f"or the 27-column official header, got {','.join(table.header)}",
                             path=table.path, line=1)
    if len(table) == 0:
        raise RecordingError("no data rows after the header", path=table.path, line=1)
    dropped: dict[str, int] = {}
    truth = _truth(table, layout, dropped)
    uwb = _tdoa(table, anchors, truth, dropped)
    imu = _imu(table, dropped) if layout == "official" else None
    if layout == "official":
        for names in OTHER_STREAMS:     # not used, but a broken row there is still a broken file
            n = table.stream_length(names)
            for name in names:
                table.floats(name, n)
    meta: dict[str, object] = {
        "source": str(table.path),
        "format": "util-csv-27" if layout == "official" else "util-csv-8",
        "dataset": "UTIL",
        "vehicle": "quadrotor",     # a Crazyflie: config_for replays its IMU with MODE_IMU_THRUST
        "constellation": constellation_from_name(table.path),
        "tdoa_mode": _tdoa_mode(table.path),
        "tag_lever_arm_m": TAG_LEVER_ARM.tolist() if layout == "official" else [0.0, 0.0, float(TAG_LEVER_ARM[2])],
        "lever_arm_assumption": ("rotated by the Vicon attitude" if layout == "official"
                                 else "no attitude in the file: vehicle assumed level, +0.0908 m in world z"),
        "rows": len(table),
        "dropped": dropped,
    }
    flight = Flight(name=table.path.stem, anchors=anchors, uwb=uwb, truth=truth, imu=imu, meta=meta)
    try:
        flight.validate()
    except FlightError as exc:  # pragma: no cover - the checks above are stricter
        raise RecordingError(str(exc), path=table.path) from None
    return flight


def _tdoa_mode(path: Path) -> str | None:
    m = re.search(r"tdoa([23])", Path(path).name)
    return f"tdoa{m.group(1)}" if m else None


def _truth(table: CsvTable, layout: str, dropped: dict[str, int]) -> Truth:
    names = POSE_STREAM_OFFICIAL if layout == "official" else POSE_STREAM_REDUCED
    n = table.stream_length(names)
    if n < 2:
        raise RecordingError(f"the pose stream needs at least 2 samples, got {n}", path=table.path, field="t_pose")
    t = seconds_to_us(table.floats("t_pose", n))
    pos = np.stack([table.floats(c, n) for c in ("pose_x", "pose_y", "pose_z")], axis=1)
    quat = None
    if layout == "official":
        q_xyzw = np.stack([table.floats(c, n) for c in ("pose_qx", "pose_qy", "pose_qz", "pose_qw")], axis=1)
        quat = normalised_quats(q_xyzw[:, [3, 0, 1, 2]], table, "pose_qw")
    _nonnegative(t, table, "t_pose")
    check_not_backwards(t, table, "t_pose")
    keep, n_rep = distinct_poses(t, table, "t_pose", pos, *([quat] if quat is not None else []))
    if n_rep:
        dropped["duplicate_pose_rows"] = n_rep
    t, pos = t[keep], pos[keep]
    if quat is not None:
        quat = quat[keep]
        tag = pos + np.einsum("nij,j->ni", quat_to_rotmat(quat), TAG_LEVER_ARM)
    else:
        tag = pos + np.array([0.0, 0.0, TAG_LEVER_ARM[2]])
    return Truth(t_us=t, pos=tag, quat=quat)


def _tdoa(table: CsvTable, anchors: Anchors, truth: Truth, dropped: dict[str, int]) -> UwbStream:
    n = table.stream_length(TDOA_STREAM)
    if n == 0:
        raise RecordingError("no TDoA measurements (the t_tdoa stream is empty)", path=table.path, field="t_tdoa")
    t = seconds_to_us(table.floats("t_tdoa", n))
    a = table.ints("idA", n)
    b = table.ints("idB", n)
    value = table.floats("tdoa_meas", n)
    _nonnegative(t, table, "t_tdoa")
    check_not_backwards(t, table, "t_tdoa")
    known = set(int(i) for i in anchors.ids)
    for name, ids in (("idA", a), ("idB", b)):
        unknown = np.nonzero(~np.isin(ids, anchors.ids))[0]
        if unknown.size:
            k = int(unknown[0])
            raise RecordingError(f"unknown anchor {int(ids[k])} (the constellation has {sorted(known)}; "
                                 f"{unknown.size} row(s) name unknown anchors)", path=table.path,
                                 line=int(table.lines[k]), field=name)
    same = np.nonzero(a == b)[0]
    if same.size:
        k = int(same[0])
        raise RecordingError(f"idA == idB == {int(a[k])}: a TDoA needs two different anchors", path=table.path,
                             line=int(table.lines[k]), field="idB")
    rep = repeated_rows(t, a, b, value)
    inside = (t >= truth.t_us[0]) & (t <= truth.t_us[-1])
    if rep.any():
        dropped["duplicate_tdoa_rows"] = int(rep.sum())
    if (~inside & ~rep).any():
        # No ground truth to score or label them against (interpolation would clamp to the end pose).
        dropped["tdoa_outside_truth_span"] = int((~inside & ~rep).sum())
    keep = ~rep & inside
    if not keep.any():
        raise RecordingError("no TDoA measurement falls within the pose stream's time span", path=table.path,
                             field="t_tdoa")
    t, a, b, value = t[keep], a[keep], b[keep], value[keep]
    p = truth.position_at(t)
    pa, pb = anchor_positions(anchors, a), anchor_positions(anchors, b)
    true_value = np.linalg.norm(p - pb, axis=1) - np.linalg.norm(p - pa, axis=1)
    return UwbStream(kind=KIND_TDOA, t_us=t, anchor_a=a, anchor_b=b, value=value, true_value=true_value)


def _imu(table: CsvTable, dropped: dict[str, int]) -> ImuStream | None:
    """Accelerometer and gyro streams -> one ImuStream on the gyro's timestamps (acc interpolated when the
    two clocks differ, as the dataset's own bag converter does)."""
    na, ng = table.stream_length(ACC_STREAM), table.stream_length(GYRO_STREAM)
    if na == 0 and ng == 0:
        return None
    if na < 2 or ng < 1:
        raise RecordingError(f"IMU streams are too short (acc {na}, gyro {ng} samples)", path=table.path,
                             field="t_acc" if na < 2 else "t_gyro")
    ta = seconds_to_us(table.floats("t_acc", na))
    tg = seconds_to_us(table.floats("t_gyro", ng))
    acc = np.stack([table.floats(c, na) for c in ACC_STREAM[1:]], axis=1) * GRAVITY
    gyro = np.stack([table.floats(c, ng) for c in GYRO_STREAM[1:]], axis=1) * DEG
    for name, t in (("t_acc", ta), ("t_gyro", tg)):
        _nonnegative(t, table, name)
        check_not_backwards(t, table, name)
    rep_a, rep_g = repeated_rows(ta, acc), repeated_rows(tg, gyro)
    for name, rep in (("duplicate_acc_rows", rep_a), ("duplicate_gyro_rows", rep_g)):
        if rep.any():
            dropped[name] = int(rep.sum())
    ta, acc, tg, gyro = ta[~rep_a], acc[~rep_a], tg[~rep_g], gyro[~rep_g]
    if np.array_equal(ta, tg):
        return ImuStream(t_us=tg, acc=acc, gyro=gyro)
    return imu_on_gyro_times(ta, acc, tg, gyro, dropped)


def _nonnegative(t: np.ndarray, table: CsvTable, field: str) -> None:
    bad = np.nonzero(t < 0)[0]
    if bad.size:
        k = int(bad[0])
        raise RecordingError(f"negative time {t[k] * 1e-6:g} s (expected seconds from the start of the log)",
                             path=table.path, line=int(table.lines[k]), field=field)
