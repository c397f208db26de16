"""The flight data model shared by the simulator, the recorded-data loaders, the twin and the streamer.

Times are integer microseconds (numpy int64) so replays are exact; everything else is SI float64.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Iterator, Mapping

import numpy as np

from harness.errors import InputError
from harness.kinds import kind_of
from protocol.messages import MeasKind

KIND_TWR = int(MeasKind.TWR)     # protocol enum meas_kind, as plain ints
KIND_TDOA = int(MeasKind.TDOA)
KIND_TOF = int(MeasKind.TOF)

#: the ground phase of a recorded flight: truth z [m] below which the tag sits in the floor's NLOS (the
#: verdict judges the flight above it, `--flight-above`; the calibrations fit on it)
FLIGHT_ABOVE_M = 0.4


class Source(IntEnum):
    """The kind of an event of a flight (Flight.events(), the streamer's frames)."""
    IMU = 0
    UWB = 1
    HEIGHT = 2
    AUX = 3      # a second measurement stream of another kind (Flight.aux: the ToF ranger)


#: the one event-ordering rule: by time, and at equal times IMU, then HEIGHT, then AUX, then UWB, so a
#: measurement sees every IMU sample, height and auxiliary measurement up to its time (the device handles
#: frames in stream order)
SOURCE_ORDER: tuple[Source, ...] = (Source.IMU, Source.HEIGHT, Source.AUX, Source.UWB)


def merge_order(times: Mapping[Source, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stream order of several time-ordered event streams: (t, source, order) where t and source are
    the streams concatenated in SOURCE_ORDER (missing sources empty) and `order` sorts them by time, then by
    SOURCE_ORDER at equal times (stable: each stream keeps its own order)."""
    parts = [np.asarray(times.get(src, np.zeros(0, np.int64)), dtype=np.int64) for src in SOURCE_ORDER]
    t = np.concatenate(parts)
    rank = np.concatenate([np.full(len(p), r, np.int8) for r, p in enumerate(parts)])
    source = np.asarray(SOURCE_ORDER, dtype=np.int8)[rank]
    return t, source, np.lexsort((rank, t))


class FlightError(InputError):
    """A flight is inconsistent (shapes, ordering, unknown anchors)."""


#: the largest float32: a finite float64 above it (1e39) becomes inf on the device
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _check_float32(name: str, what: str, arr: np.ndarray) -> None:
    """Finite values beyond the float32 range are refused at load (the device would get inf)."""
    values = np.asarray(arr, dtype=np.float64)
    bad = np.nonzero(np.isfinite(values) & (np.abs(values) > FLOAT32_MAX))
    if bad[0].size:
        k = int(bad[0][0])
        raise FlightError(f"{name}: {what} {float(values[bad][0]):g} (index {k}) is outside the device's 32-bit "
                          f"float range (|x| <= {FLOAT32_MAX:.4g})")


@dataclass(frozen=True)
class Anchors:
    """Anchor constellation: integer ids and positions [m]; optional orientations (w, x, y, z)."""

    ids: np.ndarray                      # (N,) int
    positions: np.ndarray                # (N, 3)
    orientations: np.ndarray | None = None  # (N, 4) body->world quaternions of the anchor antennas

    def __post_init__(self) -> None:
        if self.positions.shape != (len(self.ids), 3):
            raise FlightError(f"anchor positions must be ({len(self.ids)}, 3), got {self.positions.shape}")
        if len(set(int(i) for i in self.ids)) != len(self.ids):
            raise FlightError("anchor ids must be unique")

    def position(self, anchor_id: int) -> np.ndarray:
        idx = np.nonzero(self.ids == anchor_id)[0]
        if idx.size == 0:
            raise FlightError(f"unknown anchor id {anchor_id}")
        return self.positions[int(idx[0])]

    def as_dict(self) -> dict[int, np.ndarray]:
        return {int(i): self.positions[k] for k, i in enumerate(self.ids)}


@dataclass(frozen=True)
class ImuStream:
    t_us: np.ndarray    # (N,) int64, non-decreasing
    acc: np.ndarray     # (N, 3) specific force, body frame [m/s^2]
    gyro: np.ndarray    # (N, 3) body rates [rad/s]

    def __len__(self) -> int:
        return int(self.t_us.shape[0])


@dataclass(frozen=True)
class UwbStream:
    """TWR: anchor_a = anchor, anchor_b = -1, value = range. TDoA: value = d(tag, B) - d(tag, A)."""

    kind: int           # protocol enum meas_kind: a row of harness/kinds.py (KIND_TWR, KIND_TDOA, ...)
    t_us: np.ndarray    # (M,) int64, non-decreasing
    anchor_a: np.ndarray  # (M,) int
    anchor_b: np.ndarray  # (M,) int (-1 for TWR)
    value: np.ndarray   # (M,) [m]
    true_value: np.ndarray | None = None  # (M,) noiseless value, when known (simulation)

    def __len__(self) -> int:
        return int(self.t_us.shape[0])

    def take(self, sel: Any) -> UwbStream:
        """The measurements `sel` (a slice, mask or index array) selects, of the same kind."""
        tv = self.true_value
        return UwbStream(kind=self.kind, t_us=self.t_us[sel], anchor_a=self.anchor_a[sel], anchor_b=self.anchor_b[sel],
                         value=self.value[sel], true_value=None if tv is None else tv[sel])


@dataclass(frozen=True)
class HeightStream:
    """Planar mode: height pseudo-measurements of the tag (HEIGHT frames), e.g. a known constant height."""

    t_us: np.ndarray    # (H,) int64, non-decreasing
    z: np.ndarray       # (H,) height [m]
    std: float          # standard deviation [m], > 0

    def __len__(self) -> int:
        return int(self.t_us.shape[0])


@dataclass(frozen=True)
class RadioStream:
    """What the tag's radio received (LPS radio level), one row per anchor packet, time ordered.
    `uwb` of the same flight holds the measurement-level equivalent (the differences these packets
    stand for), so one flight can be flown at both levels."""

    protocol: str         # "tdoa2" | "tdoa3"
    t_us: np.ndarray      # (P,) int64 tag system time of each reception
    rx_ts: np.ndarray     # (P,) uint64 DW1000 RX timestamp, tag clock, 40 bits
    src_addr: np.ndarray  # (P,) uint64 MAC source address (anchor id = low byte)
    length: np.ndarray    # (P,) uint8 payload bytes used
    payload: np.ndarray   # (P, 128) uint8 over-the-air payload, zero padded
    true_skew_ppm: dict[int, float] = field(default_factory=dict)  # simulator truth of (cc - 1) 1e6 at the end
    true_skew_pkt: np.ndarray | None = None   # (P,) the same truth for the sender of each packet, at its time
    # (P,) the same packets parsed, with unrounded float timestamps (RadioConfig.exact_stamps), and the tag's
    # unrounded RX stamps: analysis of the engine without the DW1000 tick; never sent
    exact: list[Any] | None = None
    exact_rx: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_us.shape[0])


@dataclass(frozen=True)
class Truth:
    t_us: np.ndarray            # (K,) int64, increasing
    pos: np.ndarray             # (K, 3) position of the UWB tag [m]
    quat: np.ndarray | None = None  # (K, 4) (w, x, y, z) body->world
    vel: np.ndarray | None = None   # (K, 3) world velocity

    def position_at(self, t_us: np.ndarray) -> np.ndarray:
        """Linear interpolation of the true position at the given times (clamped at the ends)."""
        t = np.asarray(t_us, dtype=np.float64)
        tt = self.t_us.astype(np.float64)
        return np.stack([np.interp(t, tt, self.pos[:, k]) for k in range(3)], axis=-1)

    def quat_at(self, t_us: np.ndarray) -> np.ndarray:
        """(N, 4) attitude at the given times: normalised linear interpolation between the neighbouring
        samples (sign-aligned), clamped at the ends. Raises FlightError if the truth has no attitude."""
        if self.quat is None:
            raise FlightError("this truth has no attitude (quat is None)")
        t = np.atleast_1d(np.asarray(t_us, dtype=np.float64))
        tt = self.t_us.astype(np.float64)
        if tt.shape[0] == 1:
            return np.repeat(self.quat[:1] / np.linalg.norm(self.quat[0]), t.shape[0], axis=0)
        i = np.clip(np.searchsorted(tt, t, side="right") - 1, 0, tt.shape[0] - 2)
        w = np.clip((t - tt[i]) / (tt[i + 1] - tt[i]), 0.0, 1.0)[:, None]
        q0 = self.quat[i]
        q1 = self.quat[i + 1] * np.sign(np.sum(self.quat[i] * self.quat[i + 1], axis=1) + 1e-300)[:, None]
        q = (1.0 - w) * q0 + w * q1
        return q / np.linalg.norm(q, axis=1, keepdims=True)

    def attitude_at(self, t_us: np.ndarray) -> np.ndarray:
        """(N, 3) roll, pitch, yaw [rad] at the given times (the firmware's Euler formulas)."""
        q = self.quat_at(t_us)
        w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        return np.stack([roll, pitch, yaw], axis=1)


@dataclass
class Flight:
    name: str
    anchors: Anchors
    uwb: UwbStream
    truth: Truth
    imu: ImuStream | None = None
    meta: dict[str, object] = field(default_factory=dict)
    radio: RadioStream | None = None
    height: HeightStream | None = None
    # measurements of another kind streamed with the flight and fused, but not scored (no row in the results:
    # their RESULTs are not kept), e.g. a flow deck's ToF ranger (KIND_TOF)
    aux: UwbStream | None = None

    @property
    def has_imu(self) -> bool:
        return self.imu is not None and len(self.imu) > 0

    @property
    def duration_s(self) -> float:
        t0 = int(self.uwb.t_us[0]) if len(self.uwb) else 0
        t1 = int(self.uwb.t_us[-1]) if len(self.uwb) else 0
        return (t1 - t0) * 1e-6

    def validate(self) -> None:
        """Check shapes, time ordering and that every measurement names a known anchor."""
        u = self.uwb
        m = len(u)
        for name in ("anchor_a", "anchor_b", "value"):
            if getattr(u, name).shape != (m,):
                raise FlightError(f"{self.name}: uwb.{name} must have shape ({m},)")
        if m and np.any(np.diff(u.t_us) < 0):
            raise FlightError(f"{self.name}: UWB timestamps go backwards")
        for what, stream in (("measurements", u), ("auxiliary measurements", self.aux)):
            if stream is not None:
                self._check_stream(what, stream)
        for what, arr in self._device_values():
            _check_float32(self.name, what, arr)
        if self.imu is not None and len(self.imu) and np.any(np.diff(self.imu.t_us) < 0):
            raise FlightError(f"{self.name}: IMU timestamps go backwards")
        h = self.height
        if h is not None:
            if h.z.shape != h.t_us.shape or np.any(np.diff(h.t_us) < 0):
                raise FlightError(f"{self.name}: height stream must be time-ordered with one z per time")
            if not (np.all(np.isfinite(h.z)) and np.isfinite(h.std) and h.std > 0):
                raise FlightError(f"{self.name}: heights must be finite and their std > 0")

    def _check_stream(self, what: str, s: UwbStream) -> None:
        if len(s) and np.any(np.diff(s.t_us) < 0):
            raise FlightError(f"{self.name}: {what}: timestamps go backwards")
        known = set(int(i) for i in self.anchors.ids)
        missing = set(int(i) for ids in kind_of(s.kind).anchor_ids(s) for i in np.unique(ids)) - known
        if missing:
            raise FlightError(f"{self.name}: {what} name unknown anchors {sorted(missing)}")

    def _device_values(self) -> list[tuple[str, np.ndarray]]:
        """The values that travel to the device as 32-bit floats."""
        out = [("uwb value", self.uwb.value), ("anchor position", self.anchors.positions)]
        if self.aux is not None:
            out.append(("auxiliary value", self.aux.value))
        if self.imu is not None:
            out += [("IMU acceleration", self.imu.acc), ("IMU rate", self.imu.gyro)]
        return out

    def events(self) -> Iterator[tuple[int, Source, int]]:
        """Time-ordered merge: yields (t_us, source, index) in stream order (SOURCE_ORDER at equal times)."""
        t, src, idx = self.event_order()
        for k in range(len(t)):
            yield int(t[k]), Source(int(src[k])), int(idx[k])

    def event_order(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_us, source, index) arrays of every event in stream order (see events())."""
        times = {Source.UWB: self.uwb.t_us}
        if self.has_imu and self.imu is not None:
            times[Source.IMU] = self.imu.t_us
        if self.height is not None:
            times[Source.HEIGHT] = self.height.t_us
        if self.aux is not None:
            times[Source.AUX] = self.aux.t_us
        t, src, order = merge_order(times)
        idx = np.concatenate([np.arange(len(times.get(s, ()))) for s in SOURCE_ORDER])
        return t[order], src[order], idx[order]
