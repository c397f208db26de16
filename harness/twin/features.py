"""Bias-network input features (twin of bias_nn_features() in firmware_sim/core/bias_nn.h)."""

from __future__ import annotations

import numpy as np

from protocol.messages import Layout

# protocol enum layout, as plain ints
LAYOUT_NONE = int(Layout.NONE)
LAYOUT_TWR_POSE = int(Layout.TWR_POSE)    # [dp (3), roll, pitch, yaw]
LAYOUT_TDOA_POSE = int(Layout.TDOA_POSE)  # [dp_A (3), dp_B (3), roll, pitch, yaw]
LAYOUT_TWR_POS = int(Layout.TWR_POS)      # [dp (3)]
LAYOUT_TDOA_POS = int(Layout.TDOA_POS)    # [dp_A (3), dp_B (3)]

_INPUTS = {LAYOUT_TWR_POSE: 6, LAYOUT_TDOA_POSE: 9, LAYOUT_TWR_POS: 3, LAYOUT_TDOA_POS: 6}

#: bias_nn.h BIAS_NN_OOD_MARGIN: the correction fades to 0 over this excess beyond the training range
OOD_MARGIN = 0.1


def ood_fade(excess: float) -> float:
    """1 inside the training range, linearly down to 0 at OOD_MARGIN of excess (bias_nn_ood_fade)."""
    f = 1.0 - excess / OOD_MARGIN
    if not f > 0.0:
        return 0.0
    return min(f, 1.0)


def layout_inputs(layout: int) -> int:
    """Number of inputs of ``layout`` (0 if unknown), like ``bias_nn_layout_inputs``."""
    return _INPUTS.get(int(layout), 0)


def features(layout: int, tag_pos: np.ndarray, rpy: np.ndarray, anchor_a: np.ndarray,
             anchor_b: np.ndarray | None = None) -> np.ndarray:
    """Feature vector of ``layout``; ``dp = anchor - tag`` in the world frame.

    Parameters
    ----------
    layout : int
        Protocol enum ``layout``.
    tag_pos : ndarray, shape (3,)
        Estimated tag position [m].
    rpy : ndarray, shape (3,)
        Estimated roll, pitch, yaw [rad].
    anchor_a : ndarray, shape (3,)
        The TWR anchor, or TDoA anchor A.
    anchor_b : ndarray, shape (3,), optional
        TDoA anchor B (unused by TWR layouts).

    Returns
    -------
    ndarray, shape (n_in,)
        Empty for an unknown layout.
    """
    tag = np.asarray(tag_pos, dtype=np.float64)
    dp_a = np.asarray(anchor_a, dtype=np.float64) - tag
    angles = np.asarray(rpy, dtype=np.float64)
    if layout in (LAYOUT_TDOA_POSE, LAYOUT_TDOA_POS):
        if anchor_b is None:
            raise ValueError("TDoA layouts need anchor_b")
        dp_b = np.asarray(anchor_b, dtype=np.float64) - tag
    if layout == LAYOUT_TWR_POSE:
        return np.concatenate([dp_a, angles])
    if layout == LAYOUT_TDOA_POSE:
        return np.concatenate([dp_a, dp_b, angles])
    if layout == LAYOUT_TWR_POS:
        return dp_a
    if layout == LAYOUT_TDOA_POS:
        return np.concatenate([dp_a, dp_b])
    return np.zeros(0)
