"""A decoded Crazyflie uSD event log (harness/flight/formats/cf_usd.py) -> a validated `Flight`.

Events used (names as the firmware logs them; units converted to SI):

    estTDOA          idA, idB, distanceDiff [m] = d(tag, idB) - d(tag, idA)   -> UwbStream KIND_TDOA
    estDistance      id, distance [m] (TWR, used when the log has no estTDOA)  -> UwbStream KIND_TWR
    estGyroscope     gyro.x/y/z [deg/s] -> rad/s                               -> ImuStream, its timestamps
    estAcceleration  acc.x/y/z [g] -> x 9.81 m/s^2, interpolated to the gyro's timestamps
    estPose          locSrv.x/y/z [m], locSrv.qx/qy/qz/qw (mocap pose as received on board) -> Truth,
                     moved from the vehicle's origin to the UWB tag by the lever arm (body frame)
    estTOF           range.zrange [mm] -> m: the flow deck's downward ToF ranger   -> Flight.aux KIND_TOF
                     (with UsdOptions.tof; its offset from the tag point in meta["tof_offset_m"])

Every other event type is skipped and counted in meta["ignored_events"]; types not in KNOWN_UNUSED (the
Crazyflie's other estimator inputs) also give a warning in meta["warnings"].
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.flight.data import KIND_TDOA, KIND_TOF, KIND_TWR, Anchors, Flight, FlightError, ImuStream, Truth, UwbStream
from harness.flight.formats.cf_usd import UsdLog, read_usd_log
from harness.flight.formats.common import (RecordingError, anchor_positions, imu_on_gyro_times, quat_to_rotmat,
                                           repeated_rows)
from harness.flight.formats.util import DEG, GRAVITY, TAG_LEVER_ARM

TDOA, TWR, POSE, ACC, GYRO = "estTDOA", "estDistance", "estPose", "estAcceleration", "estGyroscope"
TOF = "estTOF"
VARIABLES = {TDOA: ("idA", "idB", "distanceDiff"), TWR: ("id", "distance"), TOF: ("range.zrange",),
             POSE: ("locSrv.x", "locSrv.y", "locSrv.z", "locSrv.qx", "locSrv.qy", "locSrv.qz", "locSrv.qw"),
             ACC: ("acc.x", "acc.y", "acc.z"), GYRO: ("gyro.x", "gyro.y", "gyro.z")}
#: logged by the Crazyflie's estimator but not used here: skipped quietly (others are skipped with a warning)
KNOWN_UNUSED = frozenset({"estBarometer", "estFlow", "estPosition", "estAbsoluteHeight", "estYawError",
                          "estSweepAngle", "estHeading", "estMotor"})
#: TDoA2 measures consecutive anchors (idB = idA + 1 mod N) except after a lost packet; TDoA3 any pair
#: (about 1 in N - 1 consecutive). The shared logs: 0.95-0.996 (TDoA2) against 0.16-0.18 (TDoA3).
TDOA2_MIN_CONSECUTIVE = 0.8
QUAT_NORM_TOL = 0.01
#: the ToF ranger's position in the body frame, from the vehicle's origin (the mocap pose) [m]: a flow deck
#: under the centre; z measured on the ten 0425 training flights in flight (`python -m harness.flight.tof_offset`,
#: docs/real-flights.md "The ToF ranger")
TOF_BODY = (0.0, 0.0, -0.039)
#: `uwb-hil run --recording LOG` fuses the ranger unless --no-tof, as a Crazyflie with a flow deck does: with it
#: no supervisor reset on any shared log in any configuration (docs/real-flights.md "The ToF ranger")
TOF_DEFAULT = True


@dataclass(frozen=True)
class UsdOptions:
    """How a uSD log is read: accept a CRC mismatch (still reported), the tag's lever arm (body frame, m), and
    whether the ToF ranger's measurements (estTOF) go to the estimator (Flight.aux)."""

    ignore_crc: bool = False
    lever_arm: tuple[float, float, float] = (float(TAG_LEVER_ARM[0]), float(TAG_LEVER_ARM[1]),
                                             float(TAG_LEVER_ARM[2]))
    tof: bool = False     # the reader's own default (training, calibration): `run` follows TOF_DEFAULT

    @classmethod
    def make(cls, ignore_crc: bool = False, lever_arm: Sequence[float] | str | None = None,
             tof: bool = False) -> UsdOptions:
        """From command-line values (lever_arm None = the default; a str = a calibration file of
        `uwb-hil lever-arm`)."""
        if lever_arm is None:
            return cls(ignore_crc=bool(ignore_crc), tof=bool(tof))
        if isinstance(lever_arm, str):
            from harness.flight.lever_arm import load_lever_arm
            lever_arm = load_lever_arm(Path(lever_arm))
        x, y, z = (float(v) for v in lever_arm)
        return cls(ignore_crc=bool(ignore_crc), lever_arm=(x, y, z), tof=bool(tof))


def load_cf_usd(path: Path | str, anchors: Anchors, options: UsdOptions = UsdOptions()) -> Flight:
    """A whole uSD log as a Flight (TDoA or TWR, IMU, truth with attitude), or a RecordingError."""
    log = read_usd_log(path, ignore_crc=options.ignore_crc)
    path = log.path
    _check_variables(log)
    dropped: dict[str, int] = {}
    event, kind = _uwb_source(log, dropped)
    truth = _truth(log, np.asarray(options.lever_arm, dtype=np.float64), dropped)
    uwb = _uwb(log, event, kind, anchors, truth, dropped)
    imu = _imu(log, dropped)
    ignored = {name: log.count(name) for name in log.events if name not in VARIABLES}
    unknown = sorted(name for name in ignored if name not in KNOWN_UNUSED)
    warnings = [f"unknown event type(s) skipped: " + ", ".join(f"{k} ({ignored[k]} records)" for k in unknown)
                ] if unknown else []
    if log.crc_message:
        warnings.insert(0, log.crc_message + " (loaded anyway: --ignore-crc)")
    meta: dict[str, object] = {
        "source": str(path), "format": f"cf-usd-v{log.version}", "dataset": "Crazyflie uSD event log",
        "vehicle": "quadrotor",     # config_for replays its IMU with the quadrotor model (MODE_IMU_THRUST)
        "day": path.name.split("-")[0] if "-" in path.name else None, "flight": path.name,
        "tdoa_mode": tdoa_mode(uwb, anchors) if uwb.kind == KIND_TDOA else None,
        "tag_lever_arm_m": [float(v) for v in options.lever_arm],
        "lever_arm_assumption": "rotated by the logged mocap attitude (estPose quaternion)",
        "tof_offset_m": [float(b - a) for a, b in zip(options.lever_arm, TOF_BODY)],   # ranger - tag point
        "events": {name: log.count(name) for name in sorted(log.events)},
        "ignored_events": ignored, "crc_ok": log.crc_ok, "dropped": dropped, "warnings": warnings,
    }
    aux = tof_stream(log, truth) if options.tof and log.count(TOF) else None
    flight = Flight(name=path.name, anchors=anchors, uwb=uwb, truth=truth, imu=imu, meta=meta, aux=aux)
    try:
        flight.validate()
    except FlightError as exc:  # pragma: no cover - the checks above are stricter
        raise RecordingError(str(exc), path=path) from None
    return flight


def tof_stream(log: UsdLog, truth: Truth) -> UwbStream:
    """The ranger's readings within the truth's time span, mm -> m (every reading: the estimator's model
    refuses those out of its range)."""
    t = _times(log, TOF)
    value = _column(log, TOF, VARIABLES[TOF])[:, 0] * 1e-3
    keep = (t >= truth.t_us[0]) & (t <= truth.t_us[-1])
    none = np.full(int(keep.sum()), -1, dtype=np.int64)
    return UwbStream(kind=KIND_TOF, t_us=t[keep].astype(np.int64), anchor_a=none, anchor_b=none, value=value[keep])


def tdoa_mode(uwb: UwbStream, anchors: Anchors) -> str:
    """'tdoa2' when most measurements pair consecutive anchor ids, else 'tdoa3'."""
    n = int(anchors.ids.max()) + 1
    consecutive = float(np.mean((uwb.anchor_b - uwb.anchor_a) % n == 1)) if len(uwb) else 0.0
    return "tdoa2" if consecutive >= TDOA2_MIN_CONSECUTIVE else "tdoa3"


def _check_variables(log: UsdLog) -> None:
    for et in log.types.values():
        need = VARIABLES.get(et.name)
        if need is None or et.name not in log.events:
            continue
        missing = [v for v in need if v not in et.variables]
        if missing:
            raise RecordingError(f"event {et.name!r} lacks variable(s) {missing} (declared: {list(et.variables)})",
                                 path=log.path, offset=et.header_offset)


def _column(log: UsdLog, event: str, names: tuple[str, ...]) -> np.ndarray:
    """(n, k) float64 of the named variables; a non-finite value is refused naming its record."""
    table = log.events[event]
    out = np.stack([table[v].astype(np.float64) for v in names], axis=1)
    bad = np.nonzero(~np.all(np.isfinite(out), axis=1))[0]
    if bad.size:
        k = int(bad[0])
        raise RecordingError(f"non-finite value in record {k} of {event} ({bad.size} such record(s))",
                             path=log.path, offset=int(log.offsets[event][k]))
    return out


def _times(log: UsdLog, event: str) -> np.ndarray:
    """The event's timestamps [us]; a stream going backwards is refused naming the record's offset."""
    t = log.times[event]
    back = np.nonzero(np.diff(t) < 0)[0]
    if back.size:
        k = int(back[0]) + 1
        raise RecordingError(f"{event} time goes backwards: {int(t[k])} us after {int(t[k - 1])} us ({back.size} "
                             "backward step(s) in this stream)", path=log.path, offset=int(log.offsets[event][k]))
    return t


def _truth(log: UsdLog, lever_arm: np.ndarray, dropped: dict[str, int]) -> Truth:
    if log.count(POSE) < 2:
        raise RecordingError(f"the log has {log.count(POSE)} {POSE} record(s): no ground truth (mocap pose), so "
                             "no accuracy can be judged; a replay needs at least 2 poses", path=log.path)
    t = _times(log, POSE)
    v = _column(log, POSE, VARIABLES[POSE])
    pos, quat = v[:, :3], v[:, [6, 3, 4, 5]]          # logged x, y, z, w -> stored w, x, y, z
    norm = np.linalg.norm(quat, axis=1)
    bad = np.nonzero(np.abs(norm - 1.0) > QUAT_NORM_TOL)[0]
    if bad.size:
        k = int(bad[0])
        raise RecordingError(f"{POSE} quaternion norm {norm[k]:.4f} is not 1 (corrupt attitude)", path=log.path,
                             offset=int(log.offsets[POSE][k]))
    quat = quat / norm[:, None]
    rep = repeated_rows(t, pos, quat)
    if rep.any():
        dropped["duplicate_pose_records"] = int(rep.sum())
    t, pos, quat, offs = t[~rep], pos[~rep], quat[~rep], log.offsets[POSE][~rep]
    same = np.nonzero(np.diff(t) == 0)[0]
    if same.size:
        raise RecordingError(f"two different {POSE} records with the same timestamp {int(t[same[0]])} us",
                             path=log.path, offset=int(offs[same[0] + 1]))
    tag = pos + np.einsum("nij,j->ni", quat_to_rotmat(quat), lever_arm)
    return Truth(t_us=t.astype(np.int64), pos=tag, quat=quat)


def _uwb_source(log: UsdLog, dropped: dict[str, int]) -> tuple[str, int]:
    """The UWB event of the log and its kind: estTDOA, else estDistance."""
    if log.count(TDOA):
        if log.count(TWR):
            dropped["twr_records_in_tdoa_log"] = log.count(TWR)
        return TDOA, KIND_TDOA
    if log.count(TWR):
        return TWR, KIND_TWR
    raise RecordingError(f"no UWB measurements: the log has no {TDOA} or {TWR} records (events: "
                         f"{', '.join(sorted(log.events)) or 'none'})", path=log.path)


def _uwb(log: UsdLog, event: str, kind: int, anchors: Anchors, truth: Truth, dropped: dict[str, int]) -> UwbStream:
    t = _times(log, event)
    v = _column(log, event, VARIABLES[event])
    a = v[:, 0].astype(np.int64)
    b = v[:, 1].astype(np.int64) if kind == KIND_TDOA else np.full(len(t), -1, dtype=np.int64)
    value = v[:, -1]
    _check_anchor_ids(log, event, anchors, a, b, kind)
    rep = repeated_rows(t, a, b, value)
    inside = (t >= truth.t_us[0]) & (t <= truth.t_us[-1])
    if rep.any():
        dropped[f"duplicate_{event}_records"] = int(rep.sum())
    if (~inside & ~rep).any():
        dropped[f"{event}_outside_truth_span"] = int((~inside & ~rep).sum())
    keep = ~rep & inside
    if not keep.any():
        raise RecordingError(f"no {event} record falls within the {POSE} stream's time span", path=log.path)
    t, a, b, value = t[keep], a[keep], b[keep], value[keep]
    p = truth.position_at(t)
    da = np.linalg.norm(p - anchor_positions(anchors, a), axis=1)
    true_value = da if kind == KIND_TWR else np.linalg.norm(p - anchor_positions(anchors, b), axis=1) - da
    return UwbStream(kind=kind, t_us=t.astype(np.int64), anchor_a=a, anchor_b=b, value=value, true_value=true_value)


def _check_anchor_ids(log: UsdLog, event: str, anchors: Anchors, a: np.ndarray, b: np.ndarray, kind: int) -> None:
    ids = [a] if kind == KIND_TWR else [a, b]
    for name, col in zip(VARIABLES[event], ids):
        unknown = np.nonzero(~np.isin(col, anchors.ids))[0]
        if unknown.size:
            k = int(unknown[0])
            raise RecordingError(f"{event} names anchor {int(col[k])} ({name}); the anchors are "
                                 f"{sorted(int(i) for i in anchors.ids)} ({unknown.size} such record(s))",
                                 path=log.path, offset=int(log.offsets[event][k]))
    if kind == KIND_TDOA:
        same = np.nonzero(a == b)[0]
        if same.size:
            raise RecordingError(f"{event} with idA == idB == {int(a[same[0]])}: a TDoA needs two anchors",
                                 path=log.path, offset=int(log.offsets[event][int(same[0])]))


def _imu(log: UsdLog, dropped: dict[str, int]) -> ImuStream | None:
    """Gyro and accelerometer -> one ImuStream on the gyro's timestamps (acc linearly interpolated: the two
    are sampled together but logged ~16 us apart)."""
    if not log.count(ACC) and not log.count(GYRO):
        return None
    if log.count(ACC) < 2 or log.count(GYRO) < 1:
        raise RecordingError(f"IMU streams too short ({ACC} {log.count(ACC)}, {GYRO} {log.count(GYRO)} records)",
                             path=log.path)
    ta, tg = _times(log, ACC), _times(log, GYRO)
    acc = _column(log, ACC, VARIABLES[ACC]) * GRAVITY
    gyro = _column(log, GYRO, VARIABLES[GYRO]) * DEG
    return imu_on_gyro_times(ta, acc, tg, gyro, dropped)
