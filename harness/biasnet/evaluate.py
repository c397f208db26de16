"""Measurement-level evaluation of a bias correction: error before and after, per anchor pair and overall.

Error = measured - true (from the recording's ground truth), restricted to |error| < xi (0.7 m): larger
errors are outliers for the gates, as in training. Corrected error = error - predicted bias.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from harness.biasnet.dataset import Samples


@dataclass(frozen=True)
class ErrorStats:
    n: int
    rmse_raw: float
    rmse_corrected: float
    mae_raw: float
    mae_corrected: float

    @property
    def reduction(self) -> float:
        """Relative RMSE reduction (0.4 = 40 % lower)."""
        return 1.0 - self.rmse_corrected / self.rmse_raw if self.rmse_raw > 0 else float("nan")

    def as_dict(self) -> dict[str, float]:
        return {"n": self.n, "rmse_raw": self.rmse_raw, "rmse_corrected": self.rmse_corrected,
                "mae_raw": self.mae_raw, "mae_corrected": self.mae_corrected, "reduction": self.reduction}


def error_stats(raw: np.ndarray, corrected: np.ndarray) -> ErrorStats:
    if len(raw) == 0:
        nan = float("nan")
        return ErrorStats(0, nan, nan, nan, nan)
    return ErrorStats(n=int(len(raw)), rmse_raw=float(np.sqrt(np.mean(raw ** 2))),
                      rmse_corrected=float(np.sqrt(np.mean(corrected ** 2))),
                      mae_raw=float(np.mean(np.abs(raw))), mae_corrected=float(np.mean(np.abs(corrected))))


def pair_label(a: int, b: int) -> str:
    return f"{a}" if b < 0 else f"{a}-{b}"


@dataclass(frozen=True)
class Evaluation:
    method: str
    overall: ErrorStats
    per_pair: dict[str, ErrorStats]

    def as_dict(self) -> dict[str, Any]:
        return {"method": self.method, **self.overall.as_dict(),
                "per_pair": {k: v.as_dict() for k, v in self.per_pair.items()}}


def evaluate(method: str, samples: Samples, predict: Callable[[Samples], np.ndarray]) -> Evaluation:
    pred = np.asarray(predict(samples), dtype=np.float64)
    raw = samples.bias
    corr = raw - pred
    per_pair = {}
    for a, b in sorted({(int(p[0]), int(p[1])) for p in samples.pair}):
        m = (samples.pair[:, 0] == a) & (samples.pair[:, 1] == b)
        per_pair[pair_label(a, b)] = error_stats(raw[m], corr[m])
    return Evaluation(method, error_stats(raw, corr), per_pair)
