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

from harness.errors import InputError
from harness.report.chi2 import chi2_quantile
from harness.stream.results_file import OUTCOME_RESULT

DOF = 3


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
        raise InputError("no runs")
    n = min(len(r) for r in nees_runs)
    if n <= skip:
        raise InputError(f"runs have {n} epochs, fewer than skip={skip}")
    mat = np.stack([np.asarray(r[:n], dtype=np.float64) for r in nees_runs])[:, skip:]
    mat = mat[:, np.all(np.isfinite(mat), axis=0)]
    if mat.shape[1] == 0:
        raise InputError("no epoch with a RESULT in every run")
    runs = mat.shape[0]
    avg = mat.mean(axis=0)
    lo = chi2_quantile(0.025, DOF * runs) / runs
    hi = chi2_quantile(0.975, DOF * runs) / runs
    return NeesSummary(runs=runs, epochs=int(mat.shape[1]), anees=float(avg.mean()), median=float(np.median(avg)),
                       lo=lo, hi=hi, inside=float(np.mean((avg >= lo) & (avg <= hi))),
                       above=float(np.mean(avg > hi)))
