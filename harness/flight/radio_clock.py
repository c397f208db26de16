"""Device clocks of the radio simulator: DW1000 tick counters with an offset, a skew within
+-`max_ppm`, a slow random walk of the skew, and resets (anchor reboots).

local(t) = offset_k + f (t + integral_0^t s(tau) dtau) for t in segment k (a reboot starts a new
segment with a new offset); s is piecewise linear between knots `knot_s` apart. Ticks are float64
(not wrapped; ~1e-4 tick resolution over minutes): callers round and wrap to 40 / 32 bits.
"""

from __future__ import annotations

import numpy as np

TS_FREQ = 63.8976e9


class DeviceClock:
    def __init__(self, rng: np.random.Generator, duration_s: float, max_ppm: float, walk_ppm: float,
                 knot_s: float = 0.1, skew_ppm: float | None = None, offset: float | None = None) -> None:
        n = int(np.ceil(max(duration_s, knot_s) / knot_s)) + 2
        self.knot_s = knot_s
        s0 = rng.uniform(-max_ppm, max_ppm) if skew_ppm is None else skew_ppm
        steps = rng.normal(0.0, walk_ppm * np.sqrt(knot_s), size=n - 1) if walk_ppm > 0 else np.zeros(n - 1)
        self.skew_ppm = np.clip(s0 + np.concatenate([[0.0], np.cumsum(steps)]), -max_ppm, max_ppm)
        s = self.skew_ppm * 1e-6
        # integral of the piecewise-linear skew at each knot
        self._integral = np.concatenate([[0.0], np.cumsum(0.5 * (s[1:] + s[:-1]) * knot_s)])
        self._s = s
        self.resets: list[tuple[float, float]] = [(-np.inf, rng.uniform(0, 2.0**40) if offset is None else offset)]
        self._rng = rng

    def reboot(self, t_s: float) -> None:
        """From t_s on the counter restarts from a new random value (skew unchanged: same crystal)."""
        self.resets.append((t_s, self._rng.uniform(0, 2.0**40)))

    def skew_at(self, t: np.ndarray | float) -> np.ndarray:
        """Skew [dimensionless] at true time t [s]."""
        return np.interp(t, np.arange(len(self._s)) * self.knot_s, self._s)

    def _elapsed(self, t: np.ndarray) -> np.ndarray:
        k = np.clip(np.floor(t / self.knot_s).astype(np.int64), 0, len(self._s) - 2)
        u = t - k * self.knot_s
        s0 = self._s[k]
        ds = (self._s[k + 1] - s0) / self.knot_s
        return t + self._integral[k] + s0 * u + 0.5 * ds * u * u

    def _offset(self, t: np.ndarray) -> np.ndarray:
        starts = np.array([r[0] for r in self.resets])
        offs = np.array([r[1] for r in self.resets])
        return offs[np.searchsorted(starts, t, side="right") - 1]

    def local(self, t: np.ndarray | float) -> np.ndarray:
        """Tick count at true time t [s] (t >= 0)."""
        ta = np.asarray(t, dtype=np.float64)
        return self._offset(ta) + TS_FREQ * self._elapsed(ta)

    def true_time(self, ticks: np.ndarray | float, near_s: np.ndarray | float) -> np.ndarray:
        """Inverse of local() within the segment that holds near_s (Newton, converges in 2-3 steps)."""
        target = np.asarray(ticks, dtype=np.float64) - self._offset(np.asarray(near_s, dtype=np.float64))
        t = np.asarray(near_s, dtype=np.float64).copy()
        for _ in range(4):
            t = t - (TS_FREQ * self._elapsed(t) - target) / (TS_FREQ * (1.0 + self.skew_at(t)))
        return t
