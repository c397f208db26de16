"""Writes small Crazyflie uSD event logs for the reader's tests (known values, any version, corruptions).

Written from the format's description (docs/data-formats.md), independently of the reader: struct.pack
of every record, the CRC-32 by zlib."""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

EVENTS: dict[str, tuple[int, list[str]]] = {
    "estTDOA": (9, ["idA(B)", "idB(B)", "distanceDiff(f)"]),
    "estPose": (6, ["locSrv.x(f)", "locSrv.y(f)", "locSrv.z(f)", "locSrv.qx(f)", "locSrv.qy(f)", "locSrv.qz(f)",
                    "locSrv.qw(f)"]),
    "estDistance": (3, ["id(B)", "distance(f)"]),
    "estGyroscope": (5, ["gyro.x(f)", "gyro.y(f)", "gyro.z(f)"]),
    "estAcceleration": (1, ["acc.x(f)", "acc.y(f)", "acc.z(f)"]),
    "estBarometer": (2, ["baro.asl(f)"]),
    "estTOF": (10, ["range.zrange(H)"]),
}

# a 2 x 2 x 2 m box of 8 anchors (anchor id = row), as anchor_<day>.npz holds them
ANCHOR_POS = [[-2.0, -2.0, 0.2], [2.0, -2.0, 0.2], [2.0, 2.0, 0.2], [-2.0, 2.0, 0.2],
              [-2.0, -2.0, 2.5], [2.0, -2.0, 2.5], [2.0, 2.0, 2.5], [-2.0, 2.0, 2.5]]


@dataclass
class UsdWriter:
    version: int = 2
    events: dict[str, tuple[int, list[str]]] = field(default_factory=lambda: dict(EVENTS))
    records: list[tuple[int, str, tuple[float, ...]]] = field(default_factory=list)   # (t_us, event, values)

    def add(self, t_us: int, event: str, *values: float) -> None:
        self.records.append((t_us, event, values))

    def header(self) -> bytes:
        out = bytes([0xBC]) + struct.pack("<HH", self.version, len(self.events))
        for name, (type_id, variables) in self.events.items():
            out += struct.pack("<H", type_id) + name.encode() + b"\0" + struct.pack("<H", len(variables))
            out += b"".join(v.encode() + b"\0" for v in variables)
        return out

    def record(self, t_us: int, event: str, values: tuple[float, ...]) -> bytes:
        type_id, variables = self.events[event]
        letters = "".join(v[-2] for v in variables)
        stamp = struct.pack("<Q", t_us) if self.version == 2 else struct.pack("<I", t_us // 1000)
        return struct.pack("<H", type_id) + stamp + struct.pack("<" + letters, *values)

    def offset_of(self, index: int) -> int:
        """Byte offset of record `index` in the file."""
        return len(self.header()) + sum(len(self.record(*r)) for r in self.records[:index])

    def index_of(self, event: str, k: int = 0) -> int:
        """Index (in records) of the k-th record of an event."""
        return [i for i, r in enumerate(self.records) if r[1] == event][k]

    def body(self) -> bytes:
        return self.header() + b"".join(self.record(*r) for r in self.records)

    def write(self, path: Path, body: bytes | None = None) -> Path:
        data = self.body() if body is None else body
        path.write_bytes(data + struct.pack("<I", zlib.crc32(data) & 0xFFFFFFFF))
        return path


def hover_log(version: int = 2, seconds: float = 2.0, pose: bool = True, tdoa: bool = True,
              twr: bool = False, extra: bool = True, acc_z: float = 1.0, gyro_z: float = 5.0,
              tof_mm: int | None = None) -> UsdWriter:
    """A tag hovering at (0.5, -0.3, 1.2) m, yawed 90 deg, level: IMU at 500 Hz (acc_z g, gyro_z deg/s), pose at
    100 Hz, TDoA2 pairs (k, k+1 mod 8) at 200 Hz with exact distance differences of the tag (+ the
    default lever arm rotated by the yaw), TWR to anchor k at 200 Hz, ToF ranges of tof_mm at 25 Hz. Times in
    whole ms (version 1)."""
    w = UsdWriter(version=version)
    qz = math.sin(math.pi / 4)
    qw = math.cos(math.pi / 4)
    body = (0.5, -0.3, 1.2)
    tag = tag_position(body)
    start = 1_000_000
    for k in range(int(seconds * 1000)):        # 1 ms grid
        t = start + k * 1000
        if k % 2 == 0:
            w.add(t, "estAcceleration", 0.0, 0.0, acc_z)
            w.add(t + (0 if version == 1 else 16), "estGyroscope", 0.0, 0.0, gyro_z)
        if pose and k % 10 == 0:
            w.add(t, "estPose", *body, 0.0, 0.0, qz, qw)
        if tdoa and k % 5 == 1:
            a = (k // 5) % 8
            b = (a + 1) % 8
            w.add(t, "estTDOA", a, b, _dist(tag, ANCHOR_POS[b]) - _dist(tag, ANCHOR_POS[a]))
        if twr and k % 5 == 3:
            a = (k // 5) % 8
            w.add(t, "estDistance", a, _dist(tag, ANCHOR_POS[a]))
        if tof_mm is not None and k % 40 == 7:
            w.add(t, "estTOF", tof_mm)
        if extra and k % 20 == 0:
            w.add(t, "estBarometer", 101.3)
    return w


def tag_position(body: tuple[float, float, float]) -> tuple[float, float, float]:
    """The default lever arm [-0.01245, 0.00127, 0.0908] rotated by +90 deg yaw: (-y, x, z)."""
    return body[0] - 0.00127, body[1] - 0.01245, body[2] + 0.0908


def _dist(p: tuple[float, float, float], q: list[float]) -> float:
    return math.sqrt(sum((a - b) ** 2 for a, b in zip(p, q)))


def write_anchors(path: Path) -> Path:
    import numpy as np
    np.savez(path, an_pos=np.array(ANCHOR_POS), an_quat=np.tile([0.0, 0.0, 0.0, 1.0], (8, 1)))
    return path
