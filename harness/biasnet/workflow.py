"""The steps of training and judging a bias network that both the `train`/`eval-bias`/`fit-std` commands
(harness/biasnet/cli.py, which only parses and prints) and the shipped-models recipe
(harness/biasnet/shipped.py) run: train one network with a progress display, compare a network with the
baselines on held-out flights, fit a std head."""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

from harness.biasnet.baselines import PairConstant, VoxelTable
from harness.biasnet.ceiling import HALF_WINDOW_S, fast_part
from harness.biasnet.dataset import XI_DEFAULT, Samples, build_samples
from harness.biasnet.distill import DistillConfig, DistillReport, distill
from harness.biasnet.evaluate import Evaluation, evaluate
from harness.biasnet.network import BiasModel
from harness.biasnet.train import TrainConfig, TrainReport, train_network
from harness.biasnet.recipes import SimRecipe
from harness.flight.loaders import load_recordings
from harness.biasnet.uncertainty import StdHeadConfig, calibration, with_std_head
from harness.errors import InputError, InputFileNotFound
from harness import kinds
from harness.flight.data import Flight
from harness.flight.formats.cf_usd_flight import UsdOptions
from harness.paths import SHARED_DATA
from harness.biasnet.registry import position_only_hint
from harness.twin.features import LAYOUT_TDOA_POS, LAYOUT_TDOA_POSE, LAYOUT_TWR_POS, LAYOUT_TWR_POSE


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


def distill_kind(flights: list[Flight], layout: int | None, cfg: TrainConfig, dcfg: DistillConfig, label: str,
                 xi: float = XI_DEFAULT) -> tuple[Any, DistillReport, Samples]:
    """train_kind's counterpart for an ensemble distilled into one network (distill.py): the student, the
    report (its `student` is the TrainReport of the shipped network) and the samples."""
    samples = build_samples(flights, layout, xi)
    stops: list[Callable[[], None]] = []

    def member(name: str) -> Callable[[int, float, float], None]:
        for stop in stops:   # one progress display at a time
            stop()
        stops.clear()
        update, stop = epoch_progress(f"training {label} {name}")
        stops.append(stop)
        return update
    try:
        net, _, report = distill(samples, cfg, dcfg, progress=member)
    finally:
        for stop in stops:
            stop()
    return net, report, samples


def distill_dict(report: DistillReport, dcfg: DistillConfig) -> dict[str, Any]:
    """What a model's metadata says about how its network was distilled."""
    return {"teachers": dcfg.teachers, "jitter": dcfg.jitter, "copies": dcfg.copies, "folds": report.folds,
            "teacher_best_epochs": [t.best_epoch for t in report.teachers],
            "teacher_seconds": round(sum(t.seconds for t in report.teachers), 2),
            "student_vs_teacher_m": report.student_vs_teacher_m, "out_of_fold_rmse_m": report.oof_rmse_m}


def compare(model: BiasModel, test: list[Flight], train: list[Flight], xi: float = XI_DEFAULT,
            half_window_s: float = HALF_WINDOW_S) -> dict[str, Any]:
    """The network and the two baselines (fitted on ``train``) on the measurements of ``test``, each with
    the floor and its share of the ceiling (ceiling.py, moving average over +-half_window_s), literal and
    unbiased."""
    kind = kinds.kind_of(test[0].uwb.kind).key
    net = model.network(kind)
    if net is None:
        raise InputError(f"the model has no {kind} network")
    ts = build_samples(test, net.layout, xi)
    fast = fast_part(ts, half_window_s)
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
               floor=net_eval.rmse_floor, share_of_ceiling=net_eval.share_of_ceiling,
               floor_unbiased=net_eval.rmse_floor_unbiased,
               share_of_ceiling_unbiased=net_eval.share_of_ceiling_unbiased)
    return out


# ------------------------------------------------------------------ what `train`, `eval-bias`, `fit-std` do
#: --layout choice -> feature layout, per measurement kind
LAYOUTS = {("twr", "pose"): LAYOUT_TWR_POSE, ("twr", "pos"): LAYOUT_TWR_POS,
           ("tdoa", "pose"): LAYOUT_TDOA_POSE, ("tdoa", "pos"): LAYOUT_TDOA_POS}


def kind_of(flights: list[Flight], what: str) -> str:
    """"twr" or "tdoa": the one measurement kind of `flights` (ValueError naming `what` if they mix)."""
    codes = {f.uwb.kind for f in flights}
    if len(codes) != 1:
        raise InputError(f"all {what} must have the same measurement kind")
    return kinds.kind_of(codes.pop()).key


def flights_for(recordings: list[Path] | None, anchors: Path | None, check: bool, recipe: SimRecipe,
                progress: Callable[[int, int], None] | None = None,
                usd: UsdOptions = UsdOptions()) -> tuple[list[Flight], str, list[str]]:
    """The recordings (all of one kind), else the recipe's simulated flights; with their kind and the
    sources a model's metadata names them by."""
    if recordings:
        flights = load_recordings(recordings, anchors, check=check, usd=usd)
        return flights, kind_of(flights, "training recordings"), [str(p) for p in recordings]
    flights = recipe.build(progress)
    return flights, recipe.mode, [f"sim:{recipe.mode}:{recipe.profile}:seeds {recipe.seed0}-"
                                  f"{recipe.seed0 + recipe.flights - 1}"]


def report_dict(report: TrainReport) -> dict[str, Any]:
    return {"epochs": report.epochs, "best_epoch": report.best_epoch, "n_train": report.n_train,
            "n_val": report.n_val, "seconds": round(report.seconds, 2), "stopped_by": report.stopped_by,
            "val_rmse_before_m": report.val_rmse_before_m, "val_rmse_after_m": report.val_rmse_after_m}


def train_into_model(flights: list[Flight], kind: str, sources: list[str], layout: str | None, cfg: TrainConfig,
                     xi: float, base: BiasModel, name: str | None,
                     ensemble: DistillConfig | None = None) -> tuple[BiasModel, TrainReport, Samples]:
    """Train the `kind` network on `flights` (with `ensemble`: distilled from that many teachers) and return
    `base` with it (the other kind's network kept), its metadata naming the training sources and figures."""
    lay = LAYOUTS[(kind, layout)] if layout else None
    extra: dict[str, Any] = {}
    if ensemble is None:
        net, report, samples = train_kind(flights, lay, cfg, kind, xi=xi)
    else:
        net, dreport, samples = distill_kind(flights, lay, cfg, ensemble, kind, xi=xi)
        assert dreport.student is not None
        report, extra = dreport.student, {"distilled": distill_dict(dreport, ensemble)}
    meta = dict(base.meta)
    meta[f"{kind}_trained_on"] = sources
    meta[f"{kind}_training"] = report_dict(report) | {"layout": samples.layout, "optimizer": cfg.optimizer,
                                                       "seed": cfg.seed, "xi": xi} | extra
    model = replace(base.replace(kind, net), name=name or base.name, meta=meta)
    return model, report, samples


@dataclass(frozen=True)
class EvalOptions:
    """What `eval-bias` compares on: `train` None = the recordings the model names (under `data_dir`)."""
    anchors: Path | None = None
    check: bool = True
    train: list[Path] | None = None
    data_dir: Path = SHARED_DATA
    xi: float = XI_DEFAULT
    half_window_s: float = HALF_WINDOW_S
    plot: Path | None = None
    usd: UsdOptions = UsdOptions()      # how Crazyflie uSD logs are read


def evaluate_model(model: BiasModel, model_name: str, recordings: list[Path], opts: EvalOptions) -> dict[str, Any]:
    """compare() on the held-out recordings, with the baselines fitted on the training recordings; the
    figure of bias vs azimuth when `opts.plot` is given."""
    if not opts.half_window_s > 0.0:
        raise InputError(f"--window must be a positive half width in seconds, got {opts.half_window_s}")
    test = load_recordings(recordings, opts.anchors, check=opts.check, usd=opts.usd)
    kind = kind_of(test, "evaluated recordings")
    check_attitude(model, kind, test, model_name)
    train_paths = opts.train
    if train_paths is None:  # the recordings the model was trained on, when they are recordings
        named = [p for p in model.meta.get(f"{kind}_trained_on", []) if not str(p).startswith("sim:")]
        train_paths = resolve_training_paths(named, opts.data_dir)
    train = load_recordings(train_paths, opts.anchors, check=opts.check, usd=opts.usd) if train_paths else []
    res = compare(model, test, train, opts.xi, opts.half_window_s)
    if opts.plot:
        from harness.biasnet.plots import bias_vs_azimuth
        seen = recordings[0].resolve() in {p.resolve() for p in train_paths}
        bias_vs_azimuth(model, test[0], opts.plot, note="in the training set" if seen else "held out",
                        elevation=test[0].truth.quat is not None and test[0].imu is not None)
        res["plot"] = str(opts.plot)
    return res


def resolve_training_paths(paths: list[str], data_dir: Path) -> list[Path]:
    """A model names its training recordings relative to the data folder (so it names no machine's paths):
    resolve them against `data_dir`; a path that exists as given is taken as is."""
    out: list[Path] = []
    missing: list[str] = []
    for p in paths:
        q = Path(p)
        if not q.exists() and not q.is_absolute():
            q = data_dir / q
        (out.append(q) if q.exists() else missing.append(str(p)))
    if missing:
        raise InputFileNotFound(f"baseline training recordings not found: {missing} (looked in {data_dir}, the "
                                "model names them relative to the data folder): pass --data-dir DIR, or --train "
                                "FILE ... to fit the baselines on other recordings, or --train alone for none")
    return out


def check_attitude(model: BiasModel, kind: str, test: list[Flight], model_name: str) -> None:
    """A pose-layout network needs the attitude truth of every evaluated recording."""
    net = model.network(kind)
    if net is None or net.layout not in (LAYOUT_TWR_POSE, LAYOUT_TDOA_POSE):
        return
    lacking = [f.name for f in test if f.truth.quat is None]
    if lacking:
        raise InputError(f"{model_name}: its {kind.upper()} network takes roll, pitch and yaw (pose layout "
                         f"{net.layout}), but {', '.join(lacking)} has no attitude truth: evaluate a position-only "
                         f"network instead: {position_only_hint(test[0].uwb.kind)}")


def fit_std_head(model: BiasModel, model_name: str, flights: list[Flight], kind: str, cfg: StdHeadConfig,
                 xi: float = XI_DEFAULT) -> BiasModel:
    """The model with a (re)fitted std head on its `kind` network, fitted on `flights`."""
    net = model.network(kind)
    if net is None:
        raise InputError(f"{model_name} has no {kind} network")
    return with_std_head(model, kind, build_samples(flights, net.layout, xi), cfg)
