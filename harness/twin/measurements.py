"""UWB measurement models (twins of mm_twr.c and mm_tdoa.c).

Each returns ``(h, H3)``: the predicted measurement and the nonzero (position) part of the
Jacobian ``H = [H3, 0 ... 0]`` (1, 9); or ``None`` for degenerate geometry.
"""

from __future__ import annotations

import numpy as np

#: Below this distance [m] a direction (p - a)/|p - a| is undefined.
MIN_DISTANCE = 1e-6


def _far_enough(d: float) -> bool:
    # Written as in C (`!(d >= min)` rejects): NaN counts as degenerate.
    return bool(d >= MIN_DISTANCE)


def twr(p: np.ndarray, anchor: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Range model ``h = |p - a|``, ``H3 = (p - a)^T / h``.

    Parameters
    ----------
    p : ndarray, shape (3,)
        Estimated tag position [m].
    anchor : ndarray, shape (3,)
        Anchor position [m].

    Returns
    -------
    (float, ndarray of shape (3,)) or None
        ``(h, H3)``, or None when the tag sits on the anchor.
    """
    d = np.asarray(p, dtype=np.float64) - np.asarray(anchor, dtype=np.float64)
    h = float(np.linalg.norm(d))
    if not _far_enough(h):
        return None
    return h, d / h


def tdoa(p: np.ndarray, anchor_a: np.ndarray, anchor_b: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Distance-difference model ``h = |p - b| - |p - a|``, ``H3 = (p-b)/|p-b| - (p-a)/|p-a|``.

    Parameters
    ----------
    p : ndarray, shape (3,)
        Estimated tag position [m].
    anchor_a, anchor_b : ndarray, shape (3,)
        Reference anchor A and anchor B [m].

    Returns
    -------
    (float, ndarray of shape (3,)) or None
        ``(h, H3)``, or None when the tag sits on an anchor or the anchors coincide.
    """
    p = np.asarray(p, dtype=np.float64)
    a = np.asarray(anchor_a, dtype=np.float64)
    b = np.asarray(anchor_b, dtype=np.float64)
    da = float(np.linalg.norm(p - a))
    db = float(np.linalg.norm(p - b))
    dab = float(np.linalg.norm(b - a))
    if not (_far_enough(da) and _far_enough(db) and _far_enough(dab)):
        return None
    return db - da, (p - b) / db - (p - a) / da


def within_baseline(anchor_a: np.ndarray, anchor_b: np.ndarray, diff: float) -> bool:
    """|diff| below the distance between the two anchors, in float32 as the firmware (estimator.c): a
    Crazyflie's TDoA outlier filter discards the others before its update."""
    d = np.asarray(anchor_a, dtype=np.float32) - np.asarray(anchor_b, dtype=np.float32)
    f = np.float32(diff)
    return bool(f * f < d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
