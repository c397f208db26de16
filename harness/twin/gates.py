"""Outlier gates (twins of gate_kinematic.c and gate_chi2.c)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocol.messages import MAX_ANCHORS

#: a kind without anchors (a sensor: the ToF ranger) is its own link, in the slot after the anchors'
#: (gate_kinematic.h GATE_KIN_SENSOR)
SENSOR_SLOT = MAX_ANCHORS
LINKS = MAX_ANCHORS + 1


@dataclass
class KinematicGate:
    """The kinematic gate's state (twin of gate_kinematic_t): when measurements were last fused, so that
    the window widens while they are rejected (docs/ARCHITECTURE.md, pipeline step 3)."""

    t_fused_us: int | None = None    # last UWB measurement fused (None: none since the reset)
    # per anchor: when last measured / last part of a fused measurement (0 = never)
    t_anchor_seen_us: list[int] = field(default_factory=lambda: [0] * LINKS)
    t_anchor_fused_us: list[int] = field(default_factory=lambda: [0] * LINKS)
    rejected_us: int = 0             # set by window(): how long its anchors' links had been rejected

    def reset(self) -> None:
        """Nothing fused yet (a new flight)."""
        self.t_fused_us = None
        self.t_anchor_seen_us = [0] * LINKS
        self.t_anchor_fused_us = [0] * LINKS

    def _rejected_us(self, i: int) -> int:
        """How long anchor i's links had been rejected up to its previous measurement."""
        seen, fused = self.t_anchor_seen_us[i], self.t_anchor_fused_us[i]
        return seen - fused if self.t_fused_us is not None and seen > fused else 0

    def window(self, t_us: int, ids: tuple[int, int], t_ref: int | None, dt_min: float, widen: bool = True) -> float:
        """The gate's dt [s] for a measurement at t_us between anchors ids (TWR: the same twice), t_ref the
        filter's reference time (None: none yet); marks the anchors as measured (gate_kinematic_window).
        widen=False: the nominal window only, rejected_us = 0 (a vehicle on the floor)."""
        valid = all(0 <= i < LINKS for i in ids)
        rejected = max(self._rejected_us(i) for i in ids) if (valid and widen) else 0
        self.rejected_us = rejected
        for i in ids if valid else ():
            self.t_anchor_seen_us[i] = t_us
        if t_ref is None:
            return kinematic_dt(None, dt_min)
        since = t_us - t_ref
        if widen and self.t_fused_us is not None:
            since = max(since, t_us - self.t_fused_us)  # widens while measurements are rejected
        return kinematic_dt(since + rejected, dt_min)

    def fused(self, t_us: int, ids: tuple[int, int]) -> None:
        """The measurement at t_us between ids was fused (gate_kinematic_fused); a sensor's sets only its own
        link's time (it is no UWB measurement)."""
        if ids[0] == SENSOR_SLOT:
            self.t_anchor_fused_us[SENSOR_SLOT] = t_us
            return
        if self.t_fused_us is None:
            self.t_anchor_fused_us = [t_us] * LINKS   # the first fusion starts every link's clock
        self.t_fused_us = t_us
        for i in ids:
            if 0 <= i < LINKS:
                self.t_anchor_fused_us[i] = t_us


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


#: gate_chi2.h GATE_CHI2_REOPEN_US: a link with an anchor rejected for longer skips the chi-square gate
CHI2_REOPEN_US = 200_000


def chi2_reopened(rejected_us: int, reopen_us: int = CHI2_REOPEN_US) -> bool:
    """The chi-square gate's lock-out guard (gate_chi2_reopened): open for a link whose anchors' links had
    been rejected for longer than ``reopen_us`` (KinematicGate.rejected_us)."""
    return rejected_us > reopen_us


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
