"""Filter consistency: NEES of the position estimate from RESULT covariance diagonals and ground truth.

NEES_k = e_k^T diag(var_x, var_y, var_z)^-1 e_k, e_k = estimate - truth at measurement k (3 dof; the
device reports only the diagonal of P, so cross-covariances are ignored). Over N Monte-Carlo runs of
the same flight schedule (different seeds), the average NEES per epoch of a consistent filter lies in
the two-sided 95 % chi-square interval [chi2_{0.025}(3N), chi2_{0.975}(3N)] / N for about 95 % of the
epochs; its mean over epochs (ANEES) is about 3. Larger: the filter is over-confident.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from harness.stream.streamer import OUTCOME_RESULT

DOF = 3


def chi2_quantile(p: float, k: int) -> float:
    """Wilson-Hilferty approximation of the chi-square quantile (relative error < 1 % for k >= 3)."""
    if not 0.0 < p < 1.0 or k < 1:
        raise ValueError("need 0 < p < 1 and k >= 1")
    z = _norm_ppf(p)
    c = 2.0 / (9.0 * k)
    return k * max(0.0, 1.0 - c + z * math.sqrt(c)) ** 3


def _norm_ppf(p: float) -> float:
    # Acklam's rational approximation (|error| < 1.2e-9); enough for interval bounds.
    a = (-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02, 1.383577518672690e+02,
         -3.066479806614716e+01, 2.506628277459239e+00)
    b = (-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02, 6.680131188771972e+01,
         -1.328068155288572e+01)
    c = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00, -2.549732539343734e+00,
         4.374664141464968e+00, 2.938163982698783e+00)
    d = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, 3.754408661907416e+00)
    lo = 0.02425
    if p < lo:
        q = math.sqrt(-2 * math.log(p))
        return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) / \
            ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1)
    if p > 1 - lo:
        return -_norm_ppf(1 - p)
    q = p - 0.5
    r = q * q
    return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q / \
        (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1)


def position_nees(results: np.ndarray, truth_pos: np.ndarray) -> np.ndarray:
    """NEES per measurement (NaN where there is no RESULT). results: RESULTS_DTYPE rows; truth_pos (M, 3)
    true positions at the measurement times."""
    if truth_pos.shape != (len(results), 3):
        raise ValueError(f"truth_pos must have shape ({len(results)}, 3), got {truth_pos.shape}")
    est = np.stack([results["px"], results["py"], results["pz"]], axis=1).astype(np.float64)
    var = np.stack([results["var_x"], results["var_y"], results["var_z"]], axis=1).astype(np.float64)
    out = nees_of(est - truth_pos, var)
    out[results["outcome"] != OUTCOME_RESULT] = np.nan
    return out


def nees_of(err: np.ndarray, var: np.ndarray) -> np.ndarray:
    """NEES of error vectors (M, 3) under diagonal variances (M, 3); NaN where a variance is not positive
    or the error is not finite."""
    ok = np.all(var > 0, axis=1) & np.all(np.isfinite(err), axis=1)
    out = np.full(len(err), np.nan)
    out[ok] = np.sum(err[ok] ** 2 / var[ok], axis=1)
    return out


@dataclass(frozen=True)
class NeesSummary:
    runs: int
    epochs: int
    anees: float               # mean over epochs of the run-averaged NEES (consistent: ~3)
    median: float
    lo: float                  # 95 % bounds of the run-averaged NEES
    hi: float
    inside: float              # share of epochs within [lo, hi] (consistent: ~0.95)
    above: float               # share above hi (over-confident)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def monte_carlo_nees(nees_runs: Sequence[np.ndarray], skip: int = 0) -> NeesSummary:
    """Average NEES over runs epoch by epoch (runs truncated to the shortest; the first `skip` epochs
    (convergence) left out); epochs where any run has no RESULT are dropped."""
    if not nees_runs:
        raise ValueError("no runs")
    n = min(len(r) for r in nees_runs)
    if n <= skip:
        raise ValueError(f"runs have {n} epochs, fewer than skip={skip}")
    mat = np.stack([np.asarray(r[:n], dtype=np.float64) for r in nees_runs])[:, skip:]
    mat = mat[:, np.all(np.isfinite(mat), axis=0)]
    if mat.shape[1] == 0:
        raise ValueError("no epoch with a RESULT in every run")
    runs = mat.shape[0]
    avg = mat.mean(axis=0)
    lo = chi2_quantile(0.025, DOF * runs) / runs
    hi = chi2_quantile(0.975, DOF * runs) / runs
    return NeesSummary(runs=runs, epochs=int(mat.shape[1]), anees=float(avg.mean()), median=float(np.median(avg)),
                       lo=lo, hi=hi, inside=float(np.mean((avg >= lo) & (avg <= hi))),
                       above=float(np.mean(avg > hi)))
