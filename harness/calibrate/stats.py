"""The error statistics of one trial (a flight file or a simulated flight), and their summary over trials."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from harness.flight.data import FlightError

MIN_PAIR_SHARE = 0.01
STATS_KEYS = ("n", "mean", "median", "std", "frac_gt_0.3", "frac_gt_1", "pair_spread", "noise")


class CalibrationError(FlightError):
    """Real data missing or unreadable for calibration (names the file)."""


@dataclass(frozen=True)
class ErrorStats:
    n: int
    mean: float
    median: float
    std: float
    frac_gt_03: float
    frac_gt_1: float
    pair_spread: float
    noise: float
    pair_means: dict[str, float] = field(default_factory=dict)

    def row(self) -> dict[str, float]:
        return {"n": self.n, "mean": self.mean, "median": self.median, "std": self.std,
                "frac_gt_0.3": self.frac_gt_03, "frac_gt_1": self.frac_gt_1, "pair_spread": self.pair_spread,
                "noise": self.noise}


def error_stats(err: np.ndarray, a: np.ndarray, b: np.ndarray | None = None, clip: float = 1.0) -> ErrorStats:
    """Statistics of one trial's errors (time-ordered). TDoA pairs are canonical (low id first, error sign
    flipped for the reverse pair); for TWR (b None) the "pairs" are the anchors. `noise` estimates the
    white part from successive differences within a pair (the bias varies slowly between them)."""
    err = np.asarray(err, dtype=np.float64)
    if err.size == 0:
        raise CalibrationError("no measurements to compute statistics on")
    if b is None or np.all(b < 0):
        lo, hi, e_c = a, np.full_like(a, -1), err
    else:
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        e_c = np.where(a < b, err, -err)
    ok = np.abs(err) < clip
    pair_means: dict[str, float] = {}
    keys = np.stack([lo, hi], axis=1)
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    for k, (pa, pb) in enumerate(uniq):
        m = (inv == k) & ok
        if counts[k] >= MIN_PAIR_SHARE * err.size and m.sum() > 0:
            pair_means[f"{int(pa)}-{int(pb)}" if pb >= 0 else f"{int(pa)}"] = float(e_c[m].mean())
    pm = np.array(list(pair_means.values()))
    # White-noise part: successive differences within a pair (time-ordered), |d| < 0.5 m, std / sqrt(2).
    diffs = [np.diff(e_c[inv == k]) for k in range(len(uniq))]
    d = np.concatenate(diffs) if diffs else np.zeros(0)
    d = d[np.abs(d) < 0.5]
    return ErrorStats(noise=float(d.std() / np.sqrt(2.0)) if d.size > 1 else math.nan,
                      n=int(err.size), mean=float(err[ok].mean()) if ok.any() else math.nan,
                      median=float(np.median(err)), std=float(err[ok].std()) if ok.any() else math.nan,
                      frac_gt_03=float(np.mean(np.abs(err) > 0.3)), frac_gt_1=float(np.mean(np.abs(err) > 1.0)),
                      pair_spread=float(pm.std()) if pm.size > 1 else math.nan, pair_means=pair_means)


def trial_summary(trials: Sequence[ErrorStats]) -> dict[str, dict[str, float]]:
    """Per statistic: mean over trials, min and max."""
    out: dict[str, dict[str, float]] = {}
    for key in STATS_KEYS:
        v = np.array([t.row()[key] for t in trials], dtype=np.float64)
        out[key] = {"mean": float(np.nanmean(v)), "min": float(np.nanmin(v)), "max": float(np.nanmax(v))}
    return out
