"""Outlier gates (twins of gate_kinematic.c and gate_chi2.c)."""

from __future__ import annotations

import numpy as np


def kinematic_dt(dt_us: int | None, dt_min: float) -> float:
    """Gate interval [s]: ``max(dt_us * 1e-6, dt_min)``; ``dt_min`` without a reference time (None)."""
    if dt_us is None:
        return dt_min
    return max(dt_us * 1e-6, dt_min)


def kinematic_dmax(v: np.ndarray, dt: float, a_max: float) -> float:
    """How far the tag can have moved: ``d_max = |v| dt + a_max dt^2 / 2`` [m].

    Parameters
    ----------
    v : ndarray, shape (3,)
        Velocity (only its norm is used, so body or world frame alike).
    dt : float
        Interval [s].
    a_max : float
        Tuned acceleration bound [m/s^2].
    """
    return float(np.linalg.norm(v)) * dt + 0.5 * a_max * dt * dt


def kinematic_pass(innovation: float, d_max: float, factor: float) -> bool:
    """``|y| <= factor d_max`` (factor 1 for TWR, 2 for TDoA)."""
    return bool(abs(innovation) <= factor * d_max)


def chi2_pass(innovation: float, S: float, threshold: float) -> bool:
    """Normalised innovation squared test ``y^2 / S <= threshold`` (1 degree of freedom)."""
    return bool(innovation * innovation / S <= threshold)


#: robust_update.h: Cauchy constant, iterations, smallest weight
ROBUST_CAUCHY_C = 2.3849
ROBUST_ITERATIONS = 3
ROBUST_W_MIN = 1e-4


def robust_r_var(y: float, hph: float, r_var: float) -> float:
    """R / w of the M-estimation update (twin of robust_r_var in robust_update.c): Cauchy weight of the
    residual the update with R / w would leave, iterated from w = 1."""
    sigma_c = ROBUST_CAUCHY_C * np.sqrt(r_var)
    w = 1.0
    for _ in range(ROBUST_ITERATIONS):
        rw = r_var / w
        u = (y * rw / (hph + rw)) / sigma_c
        w = 1.0 / (1.0 + u * u)
        if not w >= ROBUST_W_MIN:
            w = ROBUST_W_MIN
    return float(r_var / w)
