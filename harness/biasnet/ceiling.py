"""How much any pose-dependent correction could remove: the floor and each method's share of the ceiling.

A correction computed from where the tag is can follow the slowly varying part of the error, never the
fast one. Per flight and anchor pair, the error minus its own moving average over +-``half_window_s``
(0.25 s by default) is that fast part; its RMSE over all samples is the *floor*, and

    share_of_ceiling = (rmse_raw - rmse_corrected) / (rmse_raw - floor)

is the part of the reachable cut a method achieves (1.0 = everything slow removed). The window is a
choice, not a law: a shorter one lowers the ceiling estimate's floor towards the white noise, a longer one
counts slow drifts as removable; evaluations name the window they used.

That literal floor (the issue's definition) is biased low where windows are short: the moving average
includes the sample itself, so with n samples in the window the residual of white noise of std sigma has
variance sigma^2 (1 - 1/n) (n = 4, as on UTIL TDoA3's arbitrary pairs: 13 % low). The *unbiased* floor
scales each squared residual by n / (n - 1), which makes it sigma for white noise whatever n; a window
holding only its own sample (n = 1: residual 0 by construction) says nothing about the noise and is left
out of it (the literal floor counts it as a zero). Both are reported, with a share of the ceiling each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.biasnet.dataset import Samples
from harness.errors import InputError

HALF_WINDOW_S = 0.25


def moving_average(t_s: np.ndarray, e: np.ndarray, half_window_s: float) -> np.ndarray:
    """Mean of ``e`` over the samples with |t - t_i| <= half_window_s, for each i (t non-decreasing)."""
    if len(e) == 0:
        return np.zeros(0)
    c = np.concatenate([[0.0], np.cumsum(e, dtype=np.float64)])
    lo = np.searchsorted(t_s, t_s - half_window_s, side="left")
    hi = np.searchsorted(t_s, t_s + half_window_s, side="right")
    return (c[hi] - c[lo]) / (hi - lo)


@dataclass(frozen=True)
class FastPart:
    """The fast residual of each sample and ``n``, how many samples its window averaged (itself included)."""

    residual: np.ndarray
    n: np.ndarray

    def subset(self, mask: np.ndarray) -> "FastPart":
        return FastPart(self.residual[mask], self.n[mask])

    def floor(self) -> float:
        """The issue's floor: RMSE of the residual, every sample counted (biased low for small n)."""
        if len(self.residual) == 0:
            return float("nan")
        return float(np.sqrt(np.mean(self.residual ** 2)))

    def floor_unbiased(self) -> float:
        """RMSE with each squared residual scaled by n / (n - 1): sigma for white noise; n = 1 left out."""
        m = self.n > 1
        if not np.any(m):
            return float("nan")
        n = self.n[m].astype(np.float64)
        return float(np.sqrt(np.mean(self.residual[m] ** 2 * n / (n - 1.0))))


def window_counts(t_s: np.ndarray, half_window_s: float) -> np.ndarray:
    """How many samples lie within +-half_window_s of each (t non-decreasing), itself included."""
    lo = np.searchsorted(t_s, t_s - half_window_s, side="left")
    hi = np.searchsorted(t_s, t_s + half_window_s, side="right")
    return hi - lo


def fast_part(samples: Samples, half_window_s: float = HALF_WINDOW_S) -> FastPart:
    """The fast residual of every sample (per flight and anchor pair) with its window's sample count."""
    if samples.t_s is None:
        raise InputError("the samples carry no measurement times: the floor needs them")
    if not half_window_s > 0.0:
        raise InputError(f"the moving-average half window must be > 0 s, got {half_window_s}")
    keys = np.stack([samples.pair_keys(), samples.flight.astype(np.int64)], axis=1)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    order = np.lexsort((samples.t_s, group))  # by group, then time
    g_sorted = group[order]
    starts = np.flatnonzero(np.r_[True, g_sorted[1:] != g_sorted[:-1]])
    ends = np.r_[starts[1:], len(order)]
    out = np.empty(len(samples))
    count = np.zeros(len(samples), dtype=np.int64)
    for a, b in zip(starts, ends):
        idx = order[a:b]
        e = samples.bias[idx]
        out[idx] = e - moving_average(samples.t_s[idx], e, half_window_s)
        count[idx] = window_counts(samples.t_s[idx], half_window_s)
    return FastPart(out, count)


def share_of_ceiling(rmse_raw: float, rmse_corrected: float, floor: float) -> float:
    """(raw - corrected) / (raw - floor); NaN when there is nothing to remove (raw <= floor)."""
    gap = rmse_raw - floor
    if not np.isfinite(gap) or gap <= 0.0:
        return float("nan")
    return float((rmse_raw - rmse_corrected) / gap)
