"""Dilution of precision along a flight: how well the anchors the measurements used constrain each axis.

Per epoch (every `epoch_s` of the flight) the rows of the geometry matrix G are the gradients of the
measurement model at the true tag position for the links measured in the preceding `window_s`:
TWR `(p - a) / |p - a|`, TDoA `(p - b)/|p - b| - (p - a)/|p - a|` (each link once), plus `(0, 0, 1)` when HEIGHT pseudo-measurements are fused (planar mode). With
Q = (G^T G)^-1, HDOP = sqrt(Q_xx + Q_yy), VDOP = sqrt(Q_zz): position std ~ DOP x measurement std.
A singular G (too few or degenerate links) gives an infinite DOP.

An axis is *not observable* when its DOP is above the threshold (default 5: with 0.1-0.25 m ranging noise
that is 0.5-1.25 m of position std, and a small range bias moves the solution along it freely) in more
than half of the epochs. Then the verdict judges the observable axes (harness/report/verdict.py).

The DOP is local: it misses the *mirror image*. When the anchors an epoch used lie on one plane (three
always do), the tag's reflection across that plane has the same ranges, and nothing tells the two apart;
near-coplanar anchors (each within MIRROR_PLANE_TOL of the plane) change the reflection's ranges by at
most about twice that, below the ranging error. An epoch is *mirror-ambiguous* then, and the axis along
the plane's normal (z for anchors at about one height) counts as not observable when more than half the
epochs are, whatever its DOP. rcv_twr sequence 1 (four anchors at 0.57 m, within 3 mm of a plane; VDOP
p50 3.3) and sequence 4 (within 0.10 m; VDOP 1.7): the estimate sits on the wrong side of the anchors'
plane for 18 % and 58 % of the flight. A fused height (planar mode) removes the ambiguity of a level plane.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from harness.flight.data import Flight
from harness.kinds import kind_of

EPOCH_S = 0.5
WINDOW_S = 1.0
#: anchors within this distance [m] of one plane: their mirror image is ambiguous (2 x 0.125 m = the
#: 0.25 m TWR ranging error the firmware is configured with, std_twr)
MIRROR_PLANE_TOL = 0.125
#: a plane whose normal is within 45 degrees of vertical mirrors z; otherwise a horizontal direction
_VERTICAL_NORMAL = float(np.cos(np.radians(45.0)))


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
    mirror_share: float = 0.0   # share of epochs whose anchors are coplanar (mirror image, see above)
    mirror_axis: str = ""       # "z" or "xy": the axis along the anchors' plane normal, when ambiguous

    def as_dict(self) -> dict[str, object]:
        d = asdict(self)
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


def _epoch_links(flight: Flight, epoch_s: float, window_s: float) -> tuple[np.ndarray, list[set[tuple[int, int]]]]:
    """The epochs (t_us) and, per epoch, the links (a, b) measured in the window before it (TWR: b = a)."""
    u = flight.uwb
    if len(u) == 0:
        return np.zeros(0, np.int64), []
    t = u.t_us.astype(np.int64)
    epochs = np.arange(int(t[0]) + int(window_s * 1e6), int(t[-1]) + 1, int(epoch_s * 1e6), dtype=np.int64)
    if len(epochs) == 0:
        epochs = np.array([int(t[-1])], dtype=np.int64)
    lo = np.searchsorted(t, epochs - int(window_s * 1e6), side="left")
    hi = np.searchsorted(t, epochs, side="right")
    b_all = kind_of(u.kind).anchor_ids(u)[-1]   # B, or A again for a one-anchor kind
    links = [set(zip(u.anchor_a[lo[k]:hi[k]].tolist(), b_all[lo[k]:hi[k]].tolist())) for k in range(len(epochs))]
    return epochs, links


def dop_series(flight: Flight, epoch_s: float = EPOCH_S, window_s: float = WINDOW_S) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_us, hdop, vdop) per epoch, from the links measured in the window before each epoch."""
    epochs, links = _epoch_links(flight, epoch_s, window_s)
    pos = flight.anchors.positions
    index = {int(i): k for k, i in enumerate(flight.anchors.ids)}
    truth = flight.truth.position_at(epochs) if len(epochs) else np.zeros((0, 3))
    hdop = np.full(len(epochs), np.inf)
    vdop = np.full(len(epochs), np.inf)
    pair = kind_of(flight.uwb.kind).n_anchors == 2
    for k in range(len(epochs)):
        if len(links[k]) < 3:
            continue
        p = truth[k]
        rows = []
        for ia, ib in links[k]:
            ua = _unit(p - pos[index[int(ia)]])
            rows.append(_unit(p - pos[index[int(ib)]]) - ua if pair else ua)
        if flight.height is not None and len(flight.height):
            rows.append(np.array([0.0, 0.0, 1.0]))   # planar mode: the HEIGHT pseudo-measurement
        G = np.array(rows)
        hdop[k], vdop[k] = _dops(G)
    return epochs, hdop, vdop


def mirror_normals(flight: Flight, epoch_s: float = EPOCH_S, window_s: float = WINDOW_S) -> np.ndarray:
    """Per epoch, |z component| of the normal of the plane the anchors used lie on (within
    MIRROR_PLANE_TOL), or NaN when they do not lie on one, lie on a line, or fewer than 3 were measured."""
    epochs, links = _epoch_links(flight, epoch_s, window_s)
    pos = flight.anchors.positions
    index = {int(i): k for k, i in enumerate(flight.anchors.ids)}
    out = np.full(len(epochs), np.nan)
    for k in range(len(epochs)):
        used = sorted({int(i) for link in links[k] for i in link})
        if len(used) < 3:
            continue
        A = pos[[index[i] for i in used]]
        A = A - A.mean(axis=0)
        _, _, vt = np.linalg.svd(A)
        on_line = float(np.max(np.linalg.norm(A - np.outer(A @ vt[0], vt[0]), axis=1))) <= MIRROR_PLANE_TOL
        # anchors on a line have no one plane (every plane through it): the DOP already says so
        if not on_line and float(np.max(np.abs(A @ vt[2]))) <= MIRROR_PLANE_TOL:
            out[k] = abs(float(vt[2][2]))
    return out


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
    normals = mirror_normals(flight)
    mirrored = np.isfinite(normals)
    m_share = float(np.mean(mirrored))
    axis = ""
    if m_share > 0.5:
        axis = "z" if float(np.median(normals[mirrored])) >= _VERTICAL_NORMAL else "xy"
    z_mirror = axis == "z" and not height          # a fused height tells a level plane's two sides apart
    def pct(x: np.ndarray, q: float) -> float:   # "nearest": an infinite DOP stays infinite, not NaN
        return float(np.percentile(x, q, method="nearest"))

    return Geometry(epochs=n, hdop_p50=pct(hdop, 50), hdop_p95=pct(hdop, 95),
                    vdop_p50=pct(vdop, 50), vdop_p95=pct(vdop, 95),
                    vdop_threshold=threshold, vdop_above_share=v_share, hdop_above_share=h_share,
                    z_observable=height or (v_share <= 0.5 and not z_mirror),
                    xy_observable=h_share <= 0.5 and axis != "xy", height_fused=height,
                    mirror_share=m_share, mirror_axis=axis)
