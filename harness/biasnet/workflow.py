"""The steps of training and judging a bias network that both the `train`/`eval-bias` commands
(harness/biasnet/cli.py) and the shipped-models recipe (harness/biasnet/shipped.py) run: train one network
with a progress display, compare a network with the baselines on held-out flights."""

from __future__ import annotations

import sys
from typing import Any, Callable

from harness.biasnet.baselines import PairConstant, VoxelTable
from harness.biasnet.ceiling import HALF_WINDOW_S, fast_residual
from harness.biasnet.dataset import XI_DEFAULT, Samples, build_samples
from harness.biasnet.evaluate import Evaluation, evaluate
from harness.biasnet.model import BiasModel
from harness.biasnet.train import TrainConfig, TrainReport, train_network
from harness.biasnet.uncertainty import calibration
from harness.flight.model import KIND_TWR, Flight


def epoch_progress(label: str) -> tuple[Callable[[int, float, float], None], Callable[[], None]]:
    """A rich bar with the losses when stderr is a terminal; one line per epoch otherwise."""
    if not sys.stderr.isatty():
        def plain(epoch: int, tr: float, va: float) -> None:
            print(f"  {label} epoch {epoch:3d}  train {tr:.3e}  val {va:.3e}", file=sys.stderr, flush=True)
        return plain, (lambda: None)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
    prog = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[losses]}"),
                    TimeElapsedColumn(), transient=True)
    prog.start()
    task = prog.add_task(label, total=None, losses="")

    def update(epoch: int, tr: float, va: float) -> None:
        prog.update(task, completed=epoch, losses=f"epoch {epoch} train {tr:.2e} val {va:.2e}")
    return update, prog.stop


def train_kind(flights: list[Flight], layout: int | None, cfg: TrainConfig, label: str,
               val_flights: list[Flight] | None = None, xi: float = XI_DEFAULT) -> tuple[Any, TrainReport, Samples]:
    samples = build_samples(flights, layout, xi)
    val = build_samples(val_flights, samples.layout, xi) if val_flights else None
    update, stop = epoch_progress(f"training {label}")
    try:
        net, report = train_network(samples, cfg, val=val, progress=update)
    finally:
        stop()
    return net, report, samples


def compare(model: BiasModel, test: list[Flight], train: list[Flight], xi: float = XI_DEFAULT,
            half_window_s: float = HALF_WINDOW_S) -> dict[str, Any]:
    """The network and the two baselines (fitted on ``train``) on the measurements of ``test``, each with
    the floor and its share of the ceiling (ceiling.py, moving average over +-half_window_s)."""
    kind = "twr" if test[0].uwb.kind == KIND_TWR else "tdoa"
    net = model.network(kind)
    if net is None:
        raise ValueError(f"the model has no {kind} network")
    ts = build_samples(test, net.layout, xi)
    fast = fast_residual(ts, half_window_s)
    out: dict[str, Any] = {"kind": kind, "layout": net.layout, "model_hash": model.hash_hex,
                           "test": [f.name for f in test], "half_window_s": half_window_s}
    evals: list[Evaluation] = [evaluate("network", ts, lambda s: net.predict_batch(s.x), fast=fast)]
    if net.has_std:  # does the predicted std describe the error left on these unseen flights?
        out["std_calibration"] = calibration(net, ts)
    if train:
        tr = build_samples(train, net.layout, xi)
        out["baseline_train"] = [f.name for f in train]
        for baseline in (PairConstant(), VoxelTable()):
            fitted = baseline.fit(tr)
            evals.append(evaluate(baseline.name, ts, fitted.predict, fast=fast))
    out["methods"] = {e.method: e.as_dict() for e in evals}
    net_eval = evals[0].overall
    out.update(n=net_eval.n, rmse_raw=net_eval.rmse_raw, rmse_corrected=net_eval.rmse_corrected,
               mae_raw=net_eval.mae_raw, mae_corrected=net_eval.mae_corrected, reduction=net_eval.reduction,
               floor=net_eval.rmse_floor, share_of_ceiling=net_eval.share_of_ceiling)
    return out
