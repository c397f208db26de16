"""The std head: how large the error left after the network's correction is, at each input.

The bias network is trained for the mean (MSE, train.py). The std head is then fitted on top of its
frozen second hidden layer h2: ``log std = h2 . w + b``, by the Gaussian negative log-likelihood of the
residual r = bias - prediction,

    NLL = mean(log std + r^2 / (2 std^2)),

on samples the body was not fitted to (the validation flights), so the predicted std describes the error
on unseen data, not the training residual. The NLL is convex in (w, b) for this log-std head: a few
damped Newton steps with a small ridge converge, deterministically. The bounds std_min/std_max are
stored with the head; the firmware uses the bounded std as the measurement's standard deviation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from harness.biasnet.dataset import Samples
from harness.biasnet.network import BiasNetwork
from harness.errors import UsageError

if TYPE_CHECKING:
    from harness.biasnet.network import BiasModel


@dataclass(frozen=True)
class StdHeadConfig:
    std_min: float = 0.02     # [m] no measurement is trusted beyond 2 cm (UWB timestamp resolution ~ 1 cm)
    std_max: float = 0.5      # [m] above this the measurement is near-useless anyway (Xi is 0.7 m)
    ridge: float = 1e-3       # L2 on w (not b): keeps the head smooth where h2 is rarely active
    iterations: int = 30
    #: one std for every input (w = 0, b = its maximum-likelihood value: the RMS of the residual), i.e. a
    #: per-kind measurement std fitted to the corrected residuals instead of a pose-dependent one
    constant: bool = False
    #: multiply the fitted std by this (>= 1 trades filter consistency for accuracy, see docs/bias-network.md)
    inflate: float = 1.0

    def validate(self) -> None:
        if not 0.0 < self.std_min < self.std_max:
            raise UsageError(f"need 0 < std_min < std_max, got {self.std_min}, {self.std_max}")
        if self.ridge < 0 or self.iterations < 1:
            raise UsageError("ridge must be >= 0 and iterations >= 1")
        if not (self.inflate > 0.0 and np.isfinite(self.inflate)):
            raise UsageError(f"inflate must be a positive factor, got {self.inflate}")


def _nll(phi: np.ndarray, r2: np.ndarray, theta: np.ndarray, ridge: float) -> float:
    s = phi @ theta
    return float(np.mean(s + 0.5 * r2 * np.exp(-2.0 * s)) + 0.5 * ridge * np.sum(theta[:-1] ** 2))


def fit_std_head(net: BiasNetwork, samples: Samples, cfg: StdHeadConfig = StdHeadConfig()) -> BiasNetwork:
    """``net`` with a std head fitted on ``samples`` (whose bias the network did not see in training)."""
    cfg.validate()
    if len(samples) < 10:
        raise UsageError(f"fitting the std head needs at least 10 samples, got {len(samples)}")
    h2 = net.hidden(samples.x)
    r2 = (samples.bias - net.predict_batch(samples.x)) ** 2
    r2 = np.maximum(r2, cfg.std_min ** 2 * 1e-2)  # an exact hit must not drive log std to -inf
    phi = np.concatenate([h2, np.ones((len(h2), 1))], axis=1)
    theta = np.zeros(phi.shape[1])
    theta[-1] = 0.5 * np.log(np.mean(r2))  # start: one std for all, the maximum-likelihood constant
    if not cfg.constant:
        theta = _newton(phi, r2, theta, cfg)
    theta[-1] += np.log(cfg.inflate)
    return replace(net, w3s=theta[:-1].astype(np.float32), b3s=float(theta[-1]), std_min=cfg.std_min,
                   std_max=cfg.std_max)


def _newton(phi: np.ndarray, r2: np.ndarray, theta: np.ndarray, cfg: StdHeadConfig) -> np.ndarray:
    """Damped Newton steps on the NLL from ``theta`` (convex for a log-std head)."""
    reg = np.full(phi.shape[1], cfg.ridge)
    reg[-1] = 0.0
    f = _nll(phi, r2, theta, cfg.ridge)
    for _ in range(cfg.iterations):
        w = r2 * np.exp(-2.0 * (phi @ theta))                    # d2/ds2 of the per-sample NLL is 2w
        grad = phi.T @ (1.0 - w) / len(phi) + reg * theta
        hess = (phi * (2.0 * w)[:, None]).T @ phi / len(phi) + np.diag(reg + 1e-9)
        step = np.linalg.solve(hess, grad)
        t = 1.0
        while t > 1e-4:  # backtracking: never accept a step that raises the NLL
            cand = theta - t * step
            fc = _nll(phi, r2, cand, cfg.ridge)
            if fc <= f:
                break
            t *= 0.5
        else:
            break
        converged = f - fc < 1e-10
        theta, f = cand, fc
        if converged:
            break
    return theta


def calibration(net: BiasNetwork, samples: Samples) -> dict[str, float]:
    """How well the predicted std matches the residual on ``samples``: the mean of (r / std)^2 (1 when
    calibrated), the share of |r| < 1.96 std (0.95 for a Gaussian), and the RMS of the predicted std."""
    bias, std = net.predict_with_std_batch(samples.x)
    if not net.has_std or len(samples) == 0:
        return {"n": len(samples)}
    z = (samples.bias - bias) / std
    return {"n": int(len(samples)), "mean_z2": float(np.mean(z ** 2)), "inside_95": float(np.mean(np.abs(z) < 1.96)),
            "std_rms": float(np.sqrt(np.mean(std ** 2))),
            "residual_rms": float(np.sqrt(np.mean((samples.bias - bias) ** 2)))}


def with_std_head(model: "BiasModel", kind: str, samples: Samples,
                  cfg: StdHeadConfig = StdHeadConfig()) -> "BiasModel":
    """``model`` with a std head fitted on ``samples`` for its ``kind`` network (the bias part unchanged);
    the meta records the head's calibration on those samples."""
    from harness.biasnet.network import BiasModel
    net = model.network(kind)
    if net is None:
        raise UsageError(f"the model has no {kind} network")
    if samples.layout != net.layout:
        raise UsageError(f"samples of layout {samples.layout} for a network of layout {net.layout}")
    fitted = fit_std_head(net, samples, cfg)
    meta = dict(model.meta)
    meta[f"{kind}_std_head"] = {"fitted_on": list(samples.names), "std_min": cfg.std_min, "std_max": cfg.std_max,
                                "constant": cfg.constant, "inflate": cfg.inflate,
                                "calibration": calibration(fitted, samples)}
    return replace(model.replace(kind, fitted), meta=meta)
