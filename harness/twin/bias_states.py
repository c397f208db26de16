"""Per-anchor Gauss-Markov bias states (twin of firmware_sim/core/bias_states.c).

Each anchor's range carries a bias beta on top of the network's correction: first order Gauss-Markov,
correlation time TAU_S, stationary std STD. TWR sees beta_A, TDoA d(B) - d(A) sees beta_B - beta_A.
The link's states are propagated to the measurement and subtracted, their variance added to R; after an
accepted update each takes its share ``var h / S`` of the innovation (joint update, the cross-covariance
with the position dropped afterwards: Schmidt-style scalar filters, the EKF keeps 9 states).
"""

from __future__ import annotations

import math

ANCHORS = 16
TAU_S = 0.3
STD = 0.12


class BiasStates:
    """The states of up to ANCHORS anchors (started on their first measurement)."""

    def __init__(self) -> None:
        self.b: list[float] = []
        self.var: list[float] = []
        self.t_us: list[int] = []
        self.known: list[bool] = []
        self.reset()

    def reset(self) -> None:
        """Forget every state (a new flight)."""
        self.b = [0.0] * ANCHORS
        self.var = [0.0] * ANCHORS
        self.t_us = [0] * ANCHORS
        self.known = [False] * ANCHORS

    def _propagate(self, t_us: int, i: int) -> None:
        q = STD * STD
        if not self.known[i]:
            self.b[i], self.var[i], self.known[i] = 0.0, q, True
        elif t_us > self.t_us[i]:
            a = math.exp(-(t_us - self.t_us[i]) * 1e-6 / TAU_S)
            self.b[i] *= a
            self.var[i] = a * a * self.var[i] + q * (1.0 - a * a)
        self.t_us[i] = t_us

    def predict(self, t_us: int, a: int, b: int) -> tuple[float, float]:
        """(bias, variance) of link (a, b) at t_us (TWR: a == b)."""
        self._propagate(t_us, a)
        if a == b:
            return self.b[a], self.var[a]
        self._propagate(t_us, b)
        return self.b[b] - self.b[a], self.var[a] + self.var[b]

    def _update_one(self, i: int, h: float, y: float, S: float) -> None:
        k = self.var[i] * h / S
        self.b[i] += k * y
        self.var[i] *= 1.0 - k * h

    def update(self, a: int, b: int, y: float, S: float) -> None:
        """The states' share of an accepted update's innovation y (variance S)."""
        if not S > 0.0 or not math.isfinite(y):
            return
        if a == b:
            self._update_one(a, 1.0, y, S)
            return
        self._update_one(a, -1.0, y, S)
        self._update_one(b, 1.0, y, S)
