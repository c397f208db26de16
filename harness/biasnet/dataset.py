"""Training samples from flights: for every UWB measurement, the network's features and its bias.

Features are computed from the ground truth at training time exactly as the firmware computes them from
its estimate at run time (harness/twin/features.py is the shared definition): dp = anchor - tag in the
world frame, then roll, pitch, yaw for the pose layouts. The target is the bias, measured - true.
Only samples with |bias| < xi (the paper's Xi = 0.7 m) are kept: larger errors are outliers, the gates'
business, not the network's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.errors import InputError
from harness.flight.data import Flight, FlightError
from harness.kinds import kind_of
from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE, layout_inputs

XI_DEFAULT = 0.7


@dataclass(frozen=True)
class Samples:
    """Feature rows, targets and where each row came from (flight index, anchor pair)."""

    layout: int
    x: np.ndarray        # (N, n_in) float64
    bias: np.ndarray     # (N,) measured - true [m]
    flight: np.ndarray   # (N,) int: index into ``names``
    pair: np.ndarray     # (N, 2) int: (anchor_a, anchor_b); anchor_b = -1 for TWR
    names: tuple[str, ...]
    anchor_pos: np.ndarray | None = None  # (N, 6) positions of anchors a and b (b = NaN for TWR)
    row: np.ndarray | None = None         # (N,) index of the measurement within its flight
    t_s: np.ndarray | None = None         # (N,) measurement time [s] (ceiling.py: windows within one flight)

    def pair_keys(self) -> np.ndarray:
        """One integer per physical anchor pair: ids alone would mix different constellations."""
        if self.anchor_pos is None:
            return self.pair[:, 0].astype(np.int64) * 4096 + (self.pair[:, 1].astype(np.int64) + 1)
        key = self.pair[:, 0].astype(np.int64) * 4096 + (self.pair[:, 1].astype(np.int64) + 1)
        cm = np.nan_to_num(np.round(self.anchor_pos * 100.0), nan=-999999).astype(np.int64)
        with np.errstate(over="ignore"):  # a positional hash: wrap-around is intended
            for k in range(cm.shape[1]):
                key = key * np.int64(1000003) + cm[:, k]
        return key

    def __len__(self) -> int:
        return int(self.bias.shape[0])

    def subset(self, mask: np.ndarray) -> "Samples":
        return Samples(self.layout, self.x[mask], self.bias[mask], self.flight[mask], self.pair[mask], self.names,
                       None if self.anchor_pos is None else self.anchor_pos[mask],
                       None if self.row is None else self.row[mask],
                       None if self.t_s is None else self.t_s[mask])

    @staticmethod
    def concat(parts: list["Samples"]) -> "Samples":
        if not parts:
            raise ValueError("no samples to concatenate")
        layouts = {p.layout for p in parts}
        if len(layouts) != 1:
            raise InputError(f"cannot mix input layouts {sorted(layouts)}")
        names: list[str] = []
        flights = []
        for p in parts:
            flights.append(p.flight + len(names))
            names.extend(p.names)
        apos = None if any(p.anchor_pos is None for p in parts) else np.concatenate([p.anchor_pos for p in parts])
        rows = None if any(p.row is None for p in parts) else np.concatenate([p.row for p in parts])
        t_s = None if any(p.t_s is None for p in parts) else np.concatenate([p.t_s for p in parts])
        return Samples(parts[0].layout, np.concatenate([p.x for p in parts]), np.concatenate([p.bias for p in parts]),
                       np.concatenate(flights), np.concatenate([p.pair for p in parts]), tuple(names), apos, rows,
                       t_s)


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """(N, 4) (w, x, y, z) -> (N, 3) roll, pitch, yaw [rad]; the firmware's ekf_quat_to_rpy formulas."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=1)


def true_attitude(flight: Flight, t_us: np.ndarray) -> np.ndarray | None:
    """True roll, pitch, yaw at ``t_us`` (interpolated truth attitude), or None without attitude."""
    if flight.truth.quat is None:
        return None
    return quat_to_rpy(flight.truth.quat_at(t_us))


def default_layout(flight: Flight) -> int:
    """The pose layout when the flight has attitude truth, else the position-only one."""
    kind = kind_of(flight.uwb.kind)
    if not kind.layouts:
        raise InputError(f"{flight.name}: no bias network corrects {kind.label} measurements")
    pose, pos = kind.layouts
    return pose if flight.truth.quat is not None else pos


def geometric_value(flight: Flight, pos: np.ndarray) -> np.ndarray:
    """The noiseless measurement for tag positions ``pos`` (M, 3): range, or d(B) - d(A)."""
    u = flight.uwb
    amap = flight.anchors.as_dict()
    pa = np.array([amap[int(i)] for i in u.anchor_a]).reshape(-1, 3)
    da = np.linalg.norm(pa - pos, axis=1)
    if kind_of(u.kind).n_anchors == 1:
        return da
    pb = np.array([amap[int(i)] for i in u.anchor_b]).reshape(-1, 3)
    return np.linalg.norm(pb - pos, axis=1) - da


def flight_samples(flight: Flight, layout: int | None = None, xi: float = XI_DEFAULT,
                   index: int = 0) -> Samples:
    """Samples of one flight. ``layout`` defaults to :func:`default_layout`; |bias| >= xi is dropped."""
    u = flight.uwb
    layout = default_layout(flight) if layout is None else int(layout)
    n_in = layout_inputs(layout)
    if n_in == 0:
        raise InputError(f"unknown input layout {layout}")
    kind = kind_of(u.kind)
    if layout not in kind.layouts:
        raise InputError(f"{flight.name}: layout {layout} does not fit its {kind.label} measurements")
    pair_layout = kind.n_anchors == 2
    pos = flight.truth.position_at(u.t_us)
    rpy = None
    if layout in (LAYOUT_TWR_POSE, LAYOUT_TDOA_POSE):
        rpy = true_attitude(flight, u.t_us)
        if rpy is None:
            raise FlightError(f"{flight.name}: layout {layout} needs attitude truth; use the position-only layout")
    true_value = geometric_value(flight, pos)
    bias = np.asarray(u.value, dtype=np.float64) - true_value
    amap = flight.anchors.as_dict()
    pa = np.array([amap[int(i)] for i in u.anchor_a]).reshape(-1, 3)
    cols = [pa - pos]
    if pair_layout:
        cols.append(np.array([amap[int(i)] for i in u.anchor_b]).reshape(-1, 3) - pos)
    if rpy is not None:
        cols.append(rpy)
    x = np.concatenate(cols, axis=1)
    keep = np.isfinite(bias) & np.all(np.isfinite(x), axis=1) & (np.abs(bias) < xi)
    # Samples before the truth starts or after it ends would be labelled with a clamped position.
    keep &= (u.t_us >= flight.truth.t_us[0]) & (u.t_us <= flight.truth.t_us[-1])
    pair = np.stack([u.anchor_a, u.anchor_b], axis=1).astype(np.int64)
    pb = (np.array([amap[int(i)] for i in u.anchor_b]).reshape(-1, 3) if pair_layout
          else np.full((len(u), 3), np.nan))
    anchor_pos = np.concatenate([pa, pb], axis=1)
    return Samples(layout, x[keep], bias[keep], np.full(int(keep.sum()), index, dtype=np.int64), pair[keep],
                   (flight.name,), anchor_pos[keep], np.nonzero(keep)[0],
                   u.t_us[keep].astype(np.float64) * 1e-6)


def build_samples(flights: list[Flight], layout: int | None = None, xi: float = XI_DEFAULT) -> Samples:
    """Samples of several flights (one ``flight`` index per flight, for splitting by flight)."""
    if not flights:
        raise InputError("no flights given")
    kinds = {f.uwb.kind for f in flights}
    if len(kinds) != 1:
        raise InputError("all flights of one data set must have the same measurement kind")
    if layout is None:
        layouts = {default_layout(f) for f in flights}
        layout = min(layouts) if len(layouts) == 1 else kind_of(kinds.pop()).layouts[1]   # its position-only one
    return Samples.concat([flight_samples(f, layout, xi) for f in flights])  # concat numbers the flights


def split_by_flight(samples: Samples, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks (train, validation); whole flights go to one side, never single samples."""
    n = len(samples.names)
    if n < 2:
        raise InputError("splitting by flight needs at least 2 flights (got 1): add a flight or give a "
                         "separate validation set")
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    n_val = min(n - 1, max(1, int(round(val_fraction * n))))
    val_flights = np.sort(order[:n_val])
    val = np.isin(samples.flight, val_flights)
    return ~val, val
