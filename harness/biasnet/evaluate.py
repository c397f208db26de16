"""Measurement-level evaluation of a bias correction: error before and after, per anchor pair and overall.

Error = measured - true (from the recording's ground truth), restricted to |error| < xi (0.7 m): larger
errors are outliers for the gates, as in training. Corrected error = error - predicted bias.
Next to each method: the floor (what no pose-dependent correction can remove, ceiling.py) and the share of
the reachable cut the method achieves, both as the issue defines them and with the small-window correction
(``floor_unbiased``, ``share_of_ceiling_unbiased``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from harness.biasnet.ceiling import HALF_WINDOW_S, FastPart, fast_part, share_of_ceiling
from harness.biasnet.dataset import Samples


@dataclass(frozen=True)
class ErrorStats:
    n: int
    rmse_raw: float
    rmse_corrected: float
    mae_raw: float
    mae_corrected: float
    rmse_floor: float = float("nan")  # RMSE of the fast residual (ceiling.py); NaN when not computed
    rmse_floor_unbiased: float = float("nan")  # the same, scaled by n / (n - 1) per window (ceiling.py)

    @property
    def share_of_ceiling(self) -> float:
        return share_of_ceiling(self.rmse_raw, self.rmse_corrected, self.rmse_floor)

    @property
    def share_of_ceiling_unbiased(self) -> float:
        return share_of_ceiling(self.rmse_raw, self.rmse_corrected, self.rmse_floor_unbiased)

    @property
    def reduction(self) -> float:
        """Relative RMSE reduction (0.4 = 40 % lower)."""
        return 1.0 - self.rmse_corrected / self.rmse_raw if self.rmse_raw > 0 else float("nan")

    def as_dict(self) -> dict[str, float]:
        return {"n": self.n, "rmse_raw": self.rmse_raw, "rmse_corrected": self.rmse_corrected,
                "mae_raw": self.mae_raw, "mae_corrected": self.mae_corrected, "reduction": self.reduction,
                "floor": self.rmse_floor, "share_of_ceiling": self.share_of_ceiling,
                "floor_unbiased": self.rmse_floor_unbiased, "share_of_ceiling_unbiased": self.share_of_ceiling_unbiased}


def error_stats(raw: np.ndarray, corrected: np.ndarray, fast: FastPart | None = None) -> ErrorStats:
    """``fast``: the samples' fast residual and window counts (ceiling.fast_part), for the floors."""
    nan = float("nan")
    if len(raw) == 0:
        return ErrorStats(0, nan, nan, nan, nan)
    return ErrorStats(n=int(len(raw)), rmse_raw=float(np.sqrt(np.mean(raw ** 2))),
                      rmse_corrected=float(np.sqrt(np.mean(corrected ** 2))),
                      mae_raw=float(np.mean(np.abs(raw))), mae_corrected=float(np.mean(np.abs(corrected))),
                      rmse_floor=fast.floor() if fast is not None else nan,
                      rmse_floor_unbiased=fast.floor_unbiased() if fast is not None else nan)


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


def evaluate(method: str, samples: Samples, predict: Callable[[Samples], np.ndarray],
             half_window_s: float = HALF_WINDOW_S, fast: FastPart | None = None) -> Evaluation:
    """``fast``: precomputed fast part of ``samples`` (ceiling.fast_part, the same for every method);
    computed here when None and the samples carry times."""
    pred = np.asarray(predict(samples), dtype=np.float64)
    raw = samples.bias
    corr = raw - pred
    if fast is None and samples.t_s is not None:
        fast = fast_part(samples, half_window_s)
    per_pair = {}
    for a, b in sorted({(int(p[0]), int(p[1])) for p in samples.pair}):
        m = (samples.pair[:, 0] == a) & (samples.pair[:, 1] == b)
        per_pair[pair_label(a, b)] = error_stats(raw[m], corr[m], None if fast is None else fast.subset(m))
    return Evaluation(method, error_stats(raw, corr, fast), per_pair)
