"""`uwb-hil train`, `uwb-hil export-c`, `uwb-hil eval-bias`, `uwb-hil models` (the subcommands of the bias network)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable

from harness.biasnet.ceiling import HALF_WINDOW_S
from harness.biasnet.dataset import XI_DEFAULT
from harness.biasnet.distill import DistillConfig
from harness.biasnet.export import DEFAULT_HEADER, DEFAULT_NPZ, export_c
from harness.biasnet.network import BiasModel
from harness.biasnet.recipes import STD_HEAD_RECIPE, SimRecipe
from harness.biasnet.train import TrainConfig
from harness.biasnet.uncertainty import StdHeadConfig
from harness.biasnet.workflow import EvalOptions, evaluate_model, fit_std_head, flights_for, train_into_model
from harness import options
from harness.errors import UsageError
from harness.flight.formats.cf_usd_flight import UsdOptions
from harness.optional import require_torch
from harness.report import jsonsafe
from harness.paths import output_path, shared_data_dir


# ---------------------------------------------------------------------------------------------- progress
def _flights_progress(label: str) -> Callable[[int, int], None]:
    def show(done: int, total: int) -> None:
        print(f"\r  {label}: {done}/{total} flights", end="\n" if done == total else "", file=sys.stderr, flush=True)
    return show


# ------------------------------------------------------------------------------------------------- train
def _train_config(args: argparse.Namespace) -> TrainConfig:
    lr = args.lr if args.lr is not None else (3e-3 if args.optimizer == "adam" else 0.05)
    return TrainConfig(optimizer=args.optimizer, lr=lr, batch_size=args.batch_size, max_epochs=args.epochs,
                       patience=args.patience, val_fraction=args.val_fraction, seed=args.seed,
                       time_budget_s=args.time_budget)


def _paths(items: list[str] | None) -> list[Path] | None:
    return [Path(p) for p in items] if items else None


def _usd(args: argparse.Namespace) -> UsdOptions:
    """How Crazyflie uSD logs are read (--ignore-crc, --lever-arm)."""
    return UsdOptions.make(args.ignore_crc, args.lever_arm)


def cmd_train(args: argparse.Namespace) -> int:
    require_torch("uwb-hil train")       # before loading any data: say at once what is missing
    if args.jitter and args.ensemble is None:
        raise UsageError("--jitter applies to the distilled student: it needs --ensemble K")
    output_path(args.out, "--out")                   # before the training, not after it
    if args.header:
        output_path(args.header, "--header")
    recipe = SimRecipe(mode=args.mode, flights=args.flights, duration_s=args.duration, seed0=args.seed0,
                       profile=args.profile)
    flights, kind, sources = flights_for(_paths(args.recording), Path(args.anchors) if args.anchors else None,
                                         not args.force, recipe, _flights_progress(f"simulating {args.mode}"),
                                         _usd(args))
    base = BiasModel.load(Path(args.into)) if args.into else BiasModel(name=args.name or Path(args.out).stem)
    ensemble = DistillConfig(teachers=args.ensemble, jitter=args.jitter) if args.ensemble is not None else None
    model, report, samples = train_into_model(flights, kind, sources, args.layout, _train_config(args), args.xi,
                                              base, args.name, ensemble)
    model.save(Path(args.out))
    if args.header:
        export_c(model, Path(args.header))
    out = {"model": str(args.out), "hash": model.hash_hex, "kind": kind, **model.meta[f"{kind}_training"]}
    if args.json:
        print(jsonsafe.dumps(out))
    else:
        dist = model.meta[f"{kind}_training"].get("distilled")
        print(f"trained {kind} network (layout {samples.layout}) on {report.n_train} samples, validated on "
              f"{report.n_val} " + ("(jittered inputs, against the teacher)" if dist else "from other flights")
              + f": {report.epochs} epochs ({report.stopped_by}, best {report.best_epoch}), {report.seconds:.1f} s")
        if dist:
            print(f"distilled from {dist['teachers']} networks validated on {', '.join(dist['folds'])} (best epochs "
                  f"{dist['teacher_best_epochs']}): student - teacher RMS {dist['student_vs_teacher_m']:.4f} m; "
                  f"out-of-fold residual {dist['out_of_fold_rmse_m']:.4f} m; the student's 'validation' is the teacher")
        else:
            print(f"validation bias RMSE {report.val_rmse_before_m:.4f} m -> residual {report.val_rmse_after_m:.4f} m")
        print(f"wrote {args.out} (hash {model.hash_hex})" + (f" and {args.header}" if args.header else ""))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    output_path(args.out, "--out")
    model = BiasModel.load(Path(args.model))
    export_c(model, Path(args.out))
    print(f"wrote {args.out} (hash {model.hash_hex})")
    return 0


# --------------------------------------------------------------------------------------------- evaluation
def _print_compare(res: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table
    table = Table(title=f"{res['kind'].upper()} measurement error on {', '.join(Path(t).name for t in res['test'])} "
                        f"(|e| < {XI_DEFAULT} m, model {res['model_hash']}; floor: error minus its per-pair "
                        f"moving average over +-{res['half_window_s']:g} s; unbiased: each window's residual "
                        f"scaled by n/(n-1), windows of one sample left out)")
    for col in ("method", "n", "RMSE raw", "RMSE corr.", "MAE raw", "MAE corr.", "reduction", "floor",
                "share of ceiling", "floor (unbiased)", "share (unbiased)"):
        table.add_column(col, justify="left" if col == "method" else "right")
    for name, m in res["methods"].items():
        table.add_row(name, str(m["n"]), f"{m['rmse_raw']:.4f}", f"{m['rmse_corrected']:.4f}",
                      f"{m['mae_raw']:.4f}", f"{m['mae_corrected']:.4f}", f"{100 * m['reduction']:.1f} %",
                      f"{m['floor']:.4f}", f"{100 * m['share_of_ceiling']:.1f} %",
                      f"{m['floor_unbiased']:.4f}", f"{100 * m['share_of_ceiling_unbiased']:.1f} %")
    pairs = Table(title="network, per anchor pair")
    for col in ("pair", "n", "RMSE raw", "RMSE corr.", "MAE raw", "MAE corr."):
        pairs.add_column(col, justify="right")
    for pair, m in res["methods"]["network"]["per_pair"].items():
        pairs.add_row(pair, str(m["n"]), f"{m['rmse_raw']:.4f}", f"{m['rmse_corrected']:.4f}", f"{m['mae_raw']:.4f}",
                      f"{m['mae_corrected']:.4f}")
    console = Console(width=140)
    console.print(table)
    console.print(pairs)
    cal = res.get("std_calibration")
    if cal:
        console.print(f"network std head: predicted std (RMS) {cal['std_rms']:.4f} m for a residual of "
                      f"{cal['residual_rms']:.4f} m; mean (r/std)^2 {cal['mean_z2']:.2f} (1 = calibrated), "
                      f"|r| < 1.96 std for {100 * cal['inside_95']:.1f} % (95 % for a Gaussian)")


def cmd_eval(args: argparse.Namespace) -> int:
    if args.plot:
        output_path(args.plot, "--plot")
    opts = EvalOptions(anchors=Path(args.anchors) if args.anchors else None, check=not args.force,
                       train=None if args.train is None else [Path(p) for p in args.train],
                       data_dir=Path(args.data_dir), xi=args.xi, half_window_s=args.window,
                       plot=Path(args.plot) if args.plot else None, usd=_usd(args))
    res = evaluate_model(BiasModel.load(Path(args.model)), args.model, [Path(p) for p in args.recording], opts)
    if not res.get("n"):     # an empty table with exit 0 said nothing was wrong
        raise UsageError(f"no measurement of {', '.join(args.recording)} has |error| < --xi {args.xi:g} m: nothing "
                         "to evaluate")
    if args.json:
        print(jsonsafe.dumps(res))
    else:
        _print_compare(res)
        if "baseline_train" not in res:
            print("(no baseline: the model names no training recordings; pass --train)")
    return 0


# ------------------------------------------------------------------------------------------------ std head
def cmd_fit_std(args: argparse.Namespace) -> int:
    """Fit (or refit) the std head of one network of a model on flights its body never saw."""
    output_path(args.out, "--out")
    model = BiasModel.load(Path(args.model))
    recipe = SimRecipe(mode=args.mode, flights=args.flights, duration_s=args.duration, seed0=args.seed0,
                       spins=STD_HEAD_RECIPE.spins)
    flights, kind, _ = flights_for(_paths(args.recording), Path(args.anchors) if args.anchors else None, True,
                                   recipe, _flights_progress(f"simulating {args.mode}"), _usd(args))
    out = fit_std_head(model, args.model, flights, kind, StdHeadConfig(std_min=args.std_min, std_max=args.std_max,
                                                                   constant=args.constant, inflate=args.inflate), args.xi)
    out.save(Path(args.out))
    cal = out.meta[f"{kind}_std_head"]["calibration"]  # type: ignore[index]
    print(f"{kind} std head on {cal['n']} samples of {len(flights)} flights: predicted std RMS {cal['std_rms']:.4f} m, "
          f"residual {cal['residual_rms']:.4f} m, mean (r/std)^2 {cal['mean_z2']:.2f}")
    print(f"wrote {args.out} (hash {out.hash_hex})")
    return 0


# ------------------------------------------------------------------------------------------ shipped models
def cmd_models(args: argparse.Namespace) -> int:
    require_torch("uwb-hil models (training the shipped networks)")
    from harness.biasnet.shipped import build_shipped_models
    summary = build_shipped_models(Path(args.data), quick=args.quick, only=args.only,
                                   write_summary=not args.keep_summary)
    kept = "" if args.quick or args.keep_summary else "; models.json keeps its entry"
    for name, entry in summary.items():      # a recorded network without its recordings: say so, not silence
        if isinstance(entry, dict) and "skipped" in entry:
            print(f"uwb-hil models: {name} not built: {entry['skipped']} (looked in {args.data}){kept}",
                  file=sys.stderr)
    if args.json:
        print(jsonsafe.dumps(summary))
    return 0


# ------------------------------------------------------------------------------------------------ parser
def _add_train_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("training")
    g.add_argument("--optimizer", choices=("adam", "sgd"), default="adam",
                   help="adam (default) or sgd: mini-batch gradient descent with Nesterov momentum")
    g.add_argument("--lr", type=float, default=None, help="learning rate (default 3e-3 adam, 0.05 sgd)")
    g.add_argument("--batch-size", type=int, default=TrainConfig.batch_size, help="samples per gradient step")
    g.add_argument("--epochs", type=int, default=60, help="at most this many epochs")
    g.add_argument("--patience", type=int, default=6, help="early stopping: epochs without improvement")
    g.add_argument("--val-fraction", type=float, default=0.15, help="share of FLIGHTS held out for validation")
    g.add_argument("--time-budget", type=options.number(float, 0.0, lo_open=True, unit=" s"), default=None, help="stop after this many seconds of training")
    g.add_argument("--seed", type=int, default=0, help="seed of the weight initialisation and the batch order")
    g.add_argument("--xi", type=options.positive_m, default=XI_DEFAULT, help="keep samples with |bias| < xi [m]")


def _add_ensemble_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("ensemble (harness/biasnet/distill.py)")
    g.add_argument("--ensemble", type=int, default=None, metavar="K",
                   help="train K networks, network k validated on flight group k mod G (UTIL trial, rcv_twr "
                        "sequence) and seeded apart, and distil their mean into one network of the same size")
    g.add_argument("--jitter", type=options.number(float, 0.0), default=0.0,
                   help="with --ensemble: also fit the student on a copy of the inputs jittered by this fraction "
                        "of each input's range")


def add_commands(sub: Any) -> None:
    _add_train_parser(sub)
    _add_export_parser(sub)
    _add_eval_parser(sub)
    _add_fit_std_parser(sub)
    _add_models_parser(sub)


def _add_train_parser(sub: Any) -> None:
    tr = sub.add_parser("train", help="train a bias network (simulated flights or recordings)")
    src = tr.add_argument_group("data")
    src.add_argument("--recording", nargs="+", help="recorded flights (UTIL CSV, rcv_twr directory, Crazyflie uSD log, native .npz)")
    src.add_argument("--anchors", help="anchor file for the recordings")
    options.add_recording_read_options(src)
    src.add_argument("--force", action="store_true",
                     help="use recordings that fail the plausibility checks (units, anchor geometry, gross errors)")
    src.add_argument("--mode", choices=("twr", "tdoa"), default="twr", help="simulated: measurement kind")
    src.add_argument("--flights", type=int, default=24, help="simulated: number of training flights")
    src.add_argument("--duration", type=options.sim_duration_s, default=120.0, help="simulated: seconds per flight")
    src.add_argument("--seed0", type=int, default=0, help="simulated: first flight seed (< 1000)")
    src.add_argument("--profile", default="los", help="simulated: error profile (los, nlos)")
    src.add_argument("--layout", choices=("pose", "pos"), help="features: pose (dp + roll/pitch/yaw) or pos "
                                                                 "(dp only); default: pose when attitude is known")
    _add_train_options(tr)
    _add_ensemble_options(tr)
    out = tr.add_argument_group("output")
    out.add_argument("--out", required=True, help="model file (.npz)")
    out.add_argument("--into", help="start from this model (keeps its network of the other kind)")
    out.add_argument("--header", help="also export the C header here")
    out.add_argument("--name", help="model name")
    tr.add_argument("--json", action="store_true", help="print what was trained as JSON")
    tr.set_defaults(func=cmd_train)


def _add_export_parser(sub: Any) -> None:
    ex = sub.add_parser("export-c", help="write a model as the C header the firmware build takes")
    ex.add_argument("model", help="model .npz")
    ex.add_argument("--out", default=str(DEFAULT_HEADER), help=f"header path (default {DEFAULT_HEADER})")
    ex.set_defaults(func=cmd_export)


def _add_eval_parser(sub: Any) -> None:
    ev = sub.add_parser("eval-bias", help="measurement error before/after correction, vs simple baselines")
    ev.add_argument("--model", default=str(DEFAULT_NPZ),
                    help=f"bias model (.npz) to evaluate (default {DEFAULT_NPZ}: the simulated pose network)")
    ev.add_argument("--data-dir", default=str(shared_data_dir()),
                    help="folder the model's training recordings are named relative to (default ../shared/data, "
                         "or $UWB_HIL_DATA)")
    ev.add_argument("--recording", nargs="+", required=True, help="held-out recording(s)")
    ev.add_argument("--anchors", help="anchor file for the recordings")
    options.add_recording_read_options(ev)
    ev.add_argument("--force", action="store_true",
                    help="use recordings that fail the plausibility checks (units, anchor geometry, gross errors)")
    ev.add_argument("--train", nargs="*", default=None,
                    help="recordings to fit the baselines on (default: those the model was trained on)")
    ev.add_argument("--xi", type=options.positive_m, default=XI_DEFAULT, help="evaluate measurements with |error| < xi [m]")
    ev.add_argument("--window", type=float, default=HALF_WINDOW_S,
                    help=f"half width [s] of the per-pair moving average that defines the floor "
                         f"(default {HALF_WINDOW_S})")
    ev.add_argument("--plot", help="save measured error and predicted bias vs azimuth (paper Fig. 5) here")
    ev.add_argument("--json", action="store_true", help="print the comparison as JSON")
    ev.set_defaults(func=cmd_eval)


def _add_fit_std_parser(sub: Any) -> None:
    fs = sub.add_parser("fit-std", help="fit the std head of a model's network on flights its body never saw")
    fs.add_argument("--model", default=str(DEFAULT_NPZ), help="model .npz (its bias networks are kept)")
    fs.add_argument("--out", required=True, help="model file to write (.npz)")
    fs.add_argument("--recording", nargs="+", help="recorded flights (else simulated ones)")
    fs.add_argument("--anchors", help="anchor file for the recordings")
    options.add_recording_read_options(fs)
    fs.add_argument("--mode", choices=("twr", "tdoa"), default="tdoa", help="simulated: which network")
    fs.add_argument("--flights", type=int, default=STD_HEAD_RECIPE.flights, help="simulated flights")
    fs.add_argument("--duration", type=options.sim_duration_s, default=STD_HEAD_RECIPE.duration_s,
                    help="simulated: seconds per flight")
    fs.add_argument("--seed0", type=int, default=STD_HEAD_RECIPE.seed0,
                    help=f"simulated: first seed (default {STD_HEAD_RECIPE.seed0}: neither the shipped training "
                         "seeds 0-23 nor the evaluation seeds >= 1000; what `make models` fits the default's head on)")
    fs.add_argument("--std-min", type=float, default=StdHeadConfig.std_min, help="lower bound of the std [m]")
    fs.add_argument("--std-max", type=float, default=StdHeadConfig.std_max, help="upper bound of the std [m]")
    fs.add_argument("--xi", type=options.positive_m, default=XI_DEFAULT, help="keep samples with |bias| < xi [m]")
    fs.add_argument("--constant", action="store_true",
                    help="one std for every input: the RMS of the corrected residual (a per-kind constant)")
    fs.add_argument("--inflate", type=float, default=1.0, help="multiply the fitted std by this factor")
    fs.set_defaults(func=cmd_fit_std)


def _add_models_parser(sub: Any) -> None:
    mo = sub.add_parser("models", help="train the shipped default networks (what `make models` runs)")
    mo.add_argument("--data", default=str(shared_data_dir()),
                    help="the shared recordings (util/, rcv_twr/, cf_usd/) to train on (default $UWB_HIL_DATA, else "
                         "../shared/data)")
    mo.add_argument("--quick", action="store_true", help="small data sets (smoke test)")
    mo.add_argument("--only", choices=("sim", "nlos", "util", "rcv", "cfusd"), help="build only one of the models")
    mo.add_argument("--keep-summary", action="store_true",
                    help="leave firmware_sim/models/models.json as it is (only (re)build the files)")
    mo.add_argument("--json", action="store_true", help="print the models summary as JSON")
    mo.set_defaults(func=cmd_models)

