"""Training of the 2x50 ReLU bias network in PyTorch, converted to a :class:`BiasNetwork` for export.

Inputs are min-max scaled to [0, 1] with the training set's ranges, the target (bias) likewise with
its [out_min, out_max]; the scaling is stored with the weights, so firmware, numpy twin and PyTorch all
compute the same function. Early stopping watches a validation set made of whole flights.
Everything is seeded: the same data and config give bit-identical weights.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from harness.biasnet.dataset import Samples, split_by_flight
from harness.biasnet.network import HIDDEN, BiasNetwork
from harness.biasnet.uncertainty import StdHeadConfig, fit_std_head
from harness.errors import UsageError
from harness.optional import require_torch


@dataclass(frozen=True)
class TrainConfig:
    """How to train. The paper uses mini-batch gradient descent; Adam is offered as an option."""

    optimizer: str = "adam"         # "adam" | "sgd" (Nesterov momentum, the paper's mini-batch GD)
    lr: float = 3e-3                # Adam; SGD wants ~0.05 on the [0, 1]-scaled data
    momentum: float = 0.9
    batch_size: int = 1024          # same validation loss as 512 on 700k samples, in 0.7x the time
    max_epochs: int = 60
    patience: int = 6               # epochs without validation improvement before stopping
    min_delta: float = 1e-7         # improvement of the scaled validation MSE that counts
    val_fraction: float = 0.15      # share of flights held out for early stopping
    seed: int = 0
    threads: int = 1                # a 2x50 network gains nothing from intra-op threads; they only contend
    time_budget_s: float | None = None  # stop after this much training time (keeps the best epoch)
    #: the std head (uncertainty.py), fitted on the validation flights after training; None: no head
    std_head: StdHeadConfig | None = field(default_factory=StdHeadConfig)

    def validate(self) -> None:
        if self.optimizer not in ("sgd", "adam"):
            raise UsageError(f"optimizer must be 'sgd' or 'adam', got {self.optimizer!r}")
        if not (self.lr > 0 and self.batch_size > 0 and self.max_epochs > 0 and self.patience > 0):
            raise UsageError("lr, batch_size, max_epochs and patience must be positive")
        if not 0.0 < self.val_fraction < 1.0:
            raise UsageError("val_fraction must be in (0, 1)")


@dataclass
class TrainReport:
    epochs: int
    best_epoch: int
    train_loss: list[float] = field(default_factory=list)   # scaled MSE per epoch
    val_loss: list[float] = field(default_factory=list)
    n_train: int = 0
    n_val: int = 0
    seconds: float = 0.0
    stopped_by: str = "max_epochs"
    val_rmse_before_m: float = float("nan")  # RMSE of the raw bias on the validation flights
    val_rmse_after_m: float = float("nan")   # RMSE of bias - prediction there


ProgressFn = Callable[[int, float, float], None]


def _ranges(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    lo, hi = x.min(axis=0), x.max(axis=0)
    # A constant feature (e.g. roll of a planar data set) gets a unit-wide range around its value:
    # the firmware divides by (in_max - in_min).
    flat = hi - lo < 1e-6
    lo = np.where(flat, lo - 0.5, lo)
    hi = np.where(flat, hi + 0.5, hi)
    out_lo, out_hi = float(y.min()), float(y.max())
    if out_hi - out_lo < 1e-6:
        out_lo, out_hi = out_lo - 0.5, out_hi + 0.5
    return lo.astype(np.float32), hi.astype(np.float32), out_lo, out_hi


def train_network(samples: Samples, cfg: TrainConfig = TrainConfig(), val: Samples | None = None,
                  progress: ProgressFn | None = None) -> tuple[BiasNetwork, TrainReport]:
    """Train on ``samples``; validate on ``val`` or, if None, on whole flights split off ``samples``."""
    torch = require_torch("training a bias network")
    nn = torch.nn

    cfg.validate()
    if val is None:
        tr_mask, val_mask = split_by_flight(samples, cfg.val_fraction, cfg.seed)
        train, val = samples.subset(tr_mask), samples.subset(val_mask)
    else:
        train = samples
    if len(train) == 0 or len(val) == 0:
        raise UsageError(f"empty split: {len(train)} training and {len(val)} validation samples")

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    in_min, in_max, out_min, out_max = _ranges(train.x, train.bias)
    scale_x = (in_max - in_min).astype(np.float64)

    def tensors(s: Samples) -> tuple["torch.Tensor", "torch.Tensor"]:
        xs = ((s.x - in_min) / scale_x).astype(np.float32)
        ys = ((s.bias - out_min) / (out_max - out_min)).astype(np.float32)
        return torch.from_numpy(xs), torch.from_numpy(ys)

    xt, yt = tensors(train)
    xv, yv = tensors(val)
    n_in = train.x.shape[1]
    net = nn.Sequential(nn.Linear(n_in, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, 1))
    report = TrainReport(epochs=0, best_epoch=0, n_train=len(train), n_val=len(val))
    best = _fit_epochs(torch, net, (xt, yt), (xv, yv), cfg, report, progress)
    with torch.no_grad():
        for p, b in zip(net.parameters(), best):
            p.copy_(b)
    result = to_network(net, train.layout, in_min, in_max, out_min, out_max)
    if cfg.std_head is not None:
        result = fit_std_head(result, val, cfg.std_head)
    pred = result.predict_batch(val.x)
    report.val_rmse_before_m = float(np.sqrt(np.mean(val.bias ** 2)))
    report.val_rmse_after_m = float(np.sqrt(np.mean((val.bias - pred) ** 2)))
    return result, report


def _fit_epochs(torch: Any, net: Any, train: tuple[Any, Any], val: tuple[Any, Any], cfg: TrainConfig,
                report: TrainReport, progress: ProgressFn | None) -> list[Any]:
    """Run the epochs (early stopping on the validation loss, time budget) recording the losses and the reason
    it stopped in ``report``; the parameters of the best validation epoch."""
    xt, yt = train
    xv, yv = val
    opt = _optimizer(torch, net, cfg)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=max(1, cfg.patience // 3))
    gen = torch.Generator().manual_seed(cfg.seed)
    best = (float("inf"), [p.detach().clone() for p in net.parameters()])
    t0 = time.perf_counter()
    since_best = 0
    for epoch in range(1, cfg.max_epochs + 1):
        report.train_loss.append(_epoch(torch, net, opt, xt, yt, gen, cfg.batch_size))
        net.eval()
        with torch.no_grad():
            vloss = float(torch.mean((net(xv).squeeze(1) - yv) ** 2))
        report.val_loss.append(vloss)
        report.epochs = epoch
        sched.step(vloss)
        if progress is not None:
            progress(epoch, report.train_loss[-1], vloss)
        if vloss < best[0] - cfg.min_delta:
            best = (vloss, [p.detach().clone() for p in net.parameters()])
            report.best_epoch = epoch
            since_best = 0
        else:
            since_best += 1
            if since_best >= cfg.patience:
                report.stopped_by = "early_stopping"
                break
        if cfg.time_budget_s is not None and time.perf_counter() - t0 > cfg.time_budget_s:
            report.stopped_by = "time_budget"
            break
    report.seconds = time.perf_counter() - t0
    return best[1]


def _optimizer(torch: Any, net: Any, cfg: TrainConfig) -> Any:
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(net.parameters(), lr=cfg.lr, momentum=cfg.momentum, nesterov=True)
    # The fused kernel updates each parameter in one pass: a third of the epoch time at batch 512,
    # where per-step overhead, not arithmetic, dominates a 2x50 network.
    return torch.optim.Adam(net.parameters(), lr=cfg.lr, fused=True)


def _epoch(torch: Any, net: Any, opt: Any, xt: Any, yt: Any, gen: Any, batch_size: int) -> float:
    """One pass over the shuffled training set; returns its mean training loss."""
    net.train()
    perm = torch.randperm(len(xt), generator=gen)
    xp, yp = xt[perm], yt[perm]      # one gather per epoch; batches are then contiguous views
    total = torch.zeros((), dtype=torch.float64)
    for k in range(0, len(xt), batch_size):
        xb, yb = xp[k:k + batch_size], yp[k:k + batch_size]
        opt.zero_grad(set_to_none=True)
        loss = torch.mean((net(xb).squeeze(1) - yb) ** 2)
        loss.backward()
        opt.step()
        total += loss.detach() * len(xb)
    return float(total) / len(xt)


def to_network(net: object, layout: int, in_min: np.ndarray, in_max: np.ndarray, out_min: float,
               out_max: float) -> BiasNetwork:
    """A trained ``nn.Sequential(Linear, ReLU, Linear, ReLU, Linear)`` as a BiasNetwork (input-major)."""
    layers = [m for m in net.children() if hasattr(m, "weight")]  # type: ignore[attr-defined]
    if len(layers) != 3:
        raise ValueError("expected three Linear layers")
    w = [m.weight.detach().numpy().astype(np.float32) for m in layers]
    b = [m.bias.detach().numpy().astype(np.float32) for m in layers]
    return BiasNetwork(layout=layout, w1=w[0].T, b1=b[0], w2=w[1].T, b2=b[1], w3=w[2][0], b3=float(b[2][0]),
                       in_min=in_min, in_max=in_max, out_min=out_min, out_max=out_max)


def to_torch(net: BiasNetwork) -> object:
    """The same function as a float32 PyTorch module (scaling included): the reference for C vs torch."""
    torch = require_torch("the PyTorch reference of a bias network")
    nn = torch.nn

    class Scaled(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.body = nn.Sequential(nn.Linear(net.n_in, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
                                      nn.Linear(HIDDEN, 1))
            with torch.no_grad():
                for layer, w, bias in zip([m for m in self.body if isinstance(m, nn.Linear)],
                                          (net.w1, net.w2, net.w3.reshape(-1, 1)),
                                          (net.b1, net.b2, np.array([net.b3], np.float32))):
                    layer.weight.copy_(torch.from_numpy(np.ascontiguousarray(w.T)))
                    layer.bias.copy_(torch.from_numpy(bias))
            self.register_buffer("lo", torch.from_numpy(net.in_min))
            self.register_buffer("hi", torch.from_numpy(net.in_max))

        def forward(self, x: "torch.Tensor") -> "torch.Tensor":
            y = self.body((x - self.lo) / (self.hi - self.lo)).squeeze(-1)
            y = y * (net.out_max - net.out_min) + net.out_min
            return torch.clamp(y, net.out_min, net.out_max)

    return Scaled().eval()
