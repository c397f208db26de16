"""Estimator health from a run's results: stretches where every measurement was rejected (the filter no
longer listens to UWB: after an outage or a jump the gates can lock it out while the estimate drifts),
and the time the estimate needs to re-converge after an event."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.stream.results_file import OUTCOME_RESULT
from protocol.messages import Status


@dataclass(frozen=True)
class Streak:
    start_us: int
    end_us: int              # time of the last rejected measurement of the streak
    count: int

    @property
    def duration_s(self) -> float:
        return (self.end_us - self.start_us) * 1e-6


def rejection_streaks(results: np.ndarray, min_s: float = 1.0) -> list[Streak]:
    """Runs of consecutive answered measurements none of which was accepted, lasting >= min_s."""
    answered = results["outcome"] == OUTCOME_RESULT
    t = results["t_us"][answered].astype(np.int64)
    rejected = results["status"][answered] != Status.ACCEPTED
    out: list[Streak] = []
    if not len(t):
        return out
    # boundaries of runs of rejected measurements
    edges = np.diff(np.concatenate([[0], rejected.astype(np.int8), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
    for a, b in zip(starts.tolist(), ends.tolist()):
        s = Streak(int(t[a]), int(t[b]), b - a + 1)
        if s.duration_s >= min_s:
            out.append(s)
    return out


def reconvergence_s(t_us: np.ndarray, err: np.ndarray, t_from_us: int, threshold_m: float,
                    hold_s: float = 1.0) -> float:
    """Seconds after t_from until the position error stays below threshold_m for hold_s (inf: never)."""
    t = np.asarray(t_us, dtype=np.int64)
    idx = np.nonzero(t >= t_from_us)[0]
    if not len(idx):
        return float("inf")
    tt = t[idx]
    bad = np.asarray(err)[idx] >= threshold_m
    # next bad sample at or after each position
    nxt = np.where(bad, np.arange(len(idx)), len(idx))
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    hold_end = np.searchsorted(tt, tt + int(hold_s * 1e6))
    ok = (~bad) & (nxt >= hold_end) & (hold_end < len(idx))
    first = np.nonzero(ok)[0]
    return float((tt[first[0]] - t_from_us) * 1e-6) if len(first) else float("inf")
