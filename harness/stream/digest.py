"""The fingerprint of a flight as streamed, kept in a results file's header so that a resume can tell an
edited recording or another flight from the one recorded."""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from harness.flight.data import Flight


def flight_digest(flight: Flight) -> str:
    """SHA-256 (16 hex digits) of what is streamed: measurements, IMU, anchors, and the truth scored against."""
    digest = FlightDigest()
    digest.update(flight, last=True)
    return digest.hexdigest()


class FlightDigest:
    """`flight_digest` fed slice by slice (harness/flight/chunked.py: consecutive slices share one truth
    sample, counted once): one hash per array, combined at the end, so a 1-hour flight built in slices
    gets the digest of the same flight built whole."""

    _NAMES = ("kind", "uwb_t", "anchor_a", "anchor_b", "value", "anchor_ids", "anchor_pos", "truth_t", "truth_pos",
              "imu_t", "imu_acc", "imu_gyro")

    def __init__(self) -> None:
        self._h = {n: hashlib.sha256() for n in self._NAMES}
        self._meta: dict[str, tuple[str, int]] = {}
        self._fixed_done = False

    def _add(self, name: str, arr: Any) -> None:
        a = np.ascontiguousarray(arr)
        dtype, rows = self._meta.get(name, (str(a.dtype), 0))
        self._meta[name] = (dtype, rows + (a.shape[0] if a.ndim else 1))
        self._h[name].update(a.tobytes())

    def update(self, piece: Flight, last: bool) -> None:
        u = piece.uwb
        if not self._fixed_done:
            self._add("kind", np.int64(u.kind))
            self._add("anchor_ids", piece.anchors.ids)
            self._add("anchor_pos", piece.anchors.positions)
            self._fixed_done = True
        for name, arr in (("uwb_t", u.t_us), ("anchor_a", u.anchor_a), ("anchor_b", u.anchor_b), ("value", u.value)):
            self._add(name, arr)
        keep = slice(None) if last else slice(0, max(0, len(piece.truth.t_us) - 1))
        self._add("truth_t", piece.truth.t_us[keep])
        self._add("truth_pos", piece.truth.pos[keep])
        if piece.imu is not None:
            for name, arr in (("imu_t", piece.imu.t_us), ("imu_acc", piece.imu.acc), ("imu_gyro", piece.imu.gyro)):
                self._add(name, arr)

    def hexdigest(self) -> str:
        h = hashlib.sha256()
        for name in self._NAMES:
            if name in self._meta:
                dtype, rows = self._meta[name]
                h.update(f"{name}:{dtype}:{rows}:".encode() + self._h[name].digest())
        return h.hexdigest()[:16]
