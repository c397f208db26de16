"""Per anchor pair monitor of the bias network's corrections (twin of firmware_sim/core/nn_monitor.c).

A pair on which the correction makes the innovations worse than no correction would (exponential average
of min(y^2, 9 S) over ~64 measurements, 1.25 x the uncorrected one, after at least 64) is switched off for
the rest of the flight; ``disabled`` counts such pairs since power-up (STATS.nn_pairs_disabled).
"""

from __future__ import annotations

from dataclasses import dataclass, field

ANCHORS = 16
ALPHA = 1.0 / 64.0
MIN_SAMPLES = 64
WORSE = 1.25
CLIP = 9.0


@dataclass
class PairStat:
    ms_corr: float = 0.0
    ms_raw: float = 0.0
    n: int = 0
    off: bool = False


def _clipped_square(y: float, S: float) -> float:
    q, cap = y * y, CLIP * S
    return q if q < cap else cap


@dataclass
class NnMonitor:
    pairs: dict[tuple[int, int], PairStat] = field(default_factory=dict)
    disabled: int = 0

    def reset(self) -> None:
        """A new flight: every pair trusted again (the counter is kept)."""
        self.pairs.clear()

    def enabled(self, a: int, b: int) -> bool:
        if not (0 <= a < ANCHORS and 0 <= b < ANCHORS):
            return False
        p = self.pairs.get((a, b))
        return p is None or not p.off

    def observe(self, a: int, b: int, y: float, bias: float, S: float) -> bool:
        """One corrected measurement; True if it switched the pair off."""
        if not (0 <= a < ANCHORS and 0 <= b < ANCHORS) or not S > 0.0:
            return False
        p = self.pairs.setdefault((a, b), PairStat())
        if p.off:
            return False
        if p.n == 0:
            p.ms_corr, p.ms_raw = _clipped_square(y, S), _clipped_square(y + bias, S)
        else:
            p.ms_corr += ALPHA * (_clipped_square(y, S) - p.ms_corr)
            p.ms_raw += ALPHA * (_clipped_square(y + bias, S) - p.ms_raw)
        p.n = min(p.n + 1, 0xFFFF)
        if p.n >= MIN_SAMPLES and p.ms_corr > WORSE * p.ms_raw:
            p.off = True
            self.disabled += 1
            return True
        return False
