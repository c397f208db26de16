"""Dilution of precision along a flight: how well the anchors the measurements used constrain each axis.

Per epoch (every `epoch_s` of the flight) the rows of the geometry matrix G are the gradients of the
measurement model at the true tag position for the links measured in the preceding `window_s`:
TWR `(p - a) / |p - a|`, TDoA `(p - b)/|p - b| - (p - a)/|p - a|` (each link once), plus `(0, 0, 1)` when HEIGHT pseudo-measurements are fused (planar mode). With
Q = (G^T G)^-1, HDOP = sqrt(Q_xx + Q_yy), VDOP = sqrt(Q_zz): position std ~ DOP x measurement std.
A singular G (too few or degenerate links) gives an infinite DOP.

An axis is *not observable* when its DOP is above the threshold (default 5: with 0.1-0.25 m ranging noise
that is 0.5-1.25 m of position std, and a small range bias moves the solution along it freely) in more
than half of the epochs. Then the verdict judges the observable axes (harness/report/verdict.py).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from harness.flight.data import KIND_TDOA, Flight

EPOCH_S = 0.5
WINDOW_S = 1.0


@dataclass(frozen=True)
class Geometry:
    epochs: int
    hdop_p50: float
    hdop_p95: float
    vdop_p50: float
    vdop_p95: float
    vdop_threshold: float
    vdop_above_share: float     # share of epochs with VDOP above the threshold
    hdop_above_share: float
    z_observable: bool
    xy_observable: bool
    height_fused: bool          # planar mode: z comes from HEIGHT pseudo-measurements

    def as_dict(self) -> dict[str, object]:
        d = asdict(self)
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


def dop_series(flight: Flight, epoch_s: float = EPOCH_S, window_s: float = WINDOW_S) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_us, hdop, vdop) per epoch, from the links measured in the window before each epoch."""
    u = flight.uwb
    if len(u) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    t = u.t_us.astype(np.int64)
    epochs = np.arange(int(t[0]) + int(window_s * 1e6), int(t[-1]) + 1, int(epoch_s * 1e6), dtype=np.int64)
    if len(epochs) == 0:
        epochs = np.array([int(t[-1])], dtype=np.int64)
    ids = flight.anchors.ids
    pos = flight.anchors.positions
    index = {int(i): k for k, i in enumerate(ids)}
    truth = flight.truth.position_at(epochs)
    lo = np.searchsorted(t, epochs - int(window_s * 1e6), side="left")
    hi = np.searchsorted(t, epochs, side="right")
    hdop = np.full(len(epochs), np.inf)
    vdop = np.full(len(epochs), np.inf)
    tdoa = u.kind == KIND_TDOA
    for k in range(len(epochs)):
        a = u.anchor_a[lo[k]:hi[k]]
        b = u.anchor_b[lo[k]:hi[k]] if tdoa else a
        links = set(zip(a.tolist(), b.tolist()))
        if len(links) < 3:
            continue
        p = truth[k]
        rows = []
        for ia, ib in links:
            ua = _unit(p - pos[index[int(ia)]])
            rows.append(_unit(p - pos[index[int(ib)]]) - ua if tdoa else ua)
        if flight.height is not None and len(flight.height):
            rows.append(np.array([0.0, 0.0, 1.0]))   # planar mode: the HEIGHT pseudo-measurement
        G = np.array(rows)
        hdop[k], vdop[k] = _dops(G)
    return epochs, hdop, vdop


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 else np.zeros(3)


def _dops(G: np.ndarray) -> tuple[float, float]:
    N = G.T @ G
    # a near-singular normal matrix: the condition number says the geometry cannot resolve an axis
    if np.linalg.cond(N) > 1e12:
        return float("inf"), float("inf")
    Q = np.linalg.inv(N)
    return float(np.sqrt(max(Q[0, 0] + Q[1, 1], 0.0))), float(np.sqrt(max(Q[2, 2], 0.0)))


def geometry_summary(flight: Flight, threshold: float = 5.0) -> Geometry:
    """DOP percentiles and per-axis observability of a flight (see the module docstring)."""
    _, hdop, vdop = dop_series(flight)
    n = len(hdop)
    height = flight.height is not None and len(flight.height) > 0
    if n == 0:
        nan = float("nan")
        return Geometry(0, nan, nan, nan, nan, threshold, nan, nan, height, True, height)
    v_share = float(np.mean(vdop > threshold))
    h_share = float(np.mean(hdop > threshold))
    def pct(x: np.ndarray, q: float) -> float:   # "nearest": an infinite DOP stays infinite, not NaN
        return float(np.percentile(x, q, method="nearest"))

    return Geometry(epochs=n, hdop_p50=pct(hdop, 50), hdop_p95=pct(hdop, 95),
                    vdop_p50=pct(vdop, 50), vdop_p95=pct(vdop, 95),
                    vdop_threshold=threshold, vdop_above_share=v_share, hdop_above_share=h_share,
                    z_observable=height or v_share <= 0.5, xy_observable=h_share <= 0.5, height_fused=height)
