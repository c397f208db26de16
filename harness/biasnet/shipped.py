"""`make models`: train the networks the project ships, reproducibly, and record how well they do.

* ``sim``  -> firmware_sim/models/bias_model_default.{npz,h}: TWR and TDoA pose networks trained on
  simulated flights (seeds < 1000), compiled into the firmware that `make demo` builds, each with a
  constant std head (stage NN_STD) fitted on further simulated flights (recipes.STD_HEAD_RECIPE).
* ``util`` -> firmware_sim/models/util_tdoa_pos.npz: position-only TDoA network on UTIL const1/const2
  trials 1-4 (the reduced data has no attitude); evaluated on trial 5.
* ``rcv``  -> firmware_sim/models/rcv_twr.npz: TWR pose network on rcv_twr sequences 1-4, evaluated on 5.
  Both recorded networks are distilled from RECORDED_TEACHERS networks (distill.py; --quick: one network).
* ``cfusd`` -> firmware_sim/models/cf_tdoa_pose.npz: TDoA pose network (dp_A, dp_B, roll, pitch, yaw) on the
  Crazyflie uSD logs' line-of-sight flights minus the evaluation flights 0425-traj3, 8, 13, 18 (recipes.py);
  distilled from one teacher per training flight (leave-one-flight-out folds); evaluated on those four
  (each, and pooled) and on the two shelf flights of 0426 (non-line-of-sight, never trained on). Every log
  is read with the tag's lever arm calibrated on other flights (recipes.cf_usd_lever_arms), the tag point
  the replays of docs/real-flights.md are judged on.
* ``nlos`` -> firmware_sim/models/bias_model_nlos.npz: TWR and TDoA pose networks trained on simulated
  flights in the obstacle arena (profile "nlos", seeds < 1000), for flying there (`uwb-hil fly --profile
  nlos --model ...`): the network learns the space it flies in, as the paper's was. Not compiled in.
Each model's file carries its provenance and held-out figures (``meta``); firmware_sim/models/models.json
collects them with the command, so the docs can quote them. Only the simulated network's files are
committed; the two trained on ../shared/data are rebuilt from it (seeded: the same hashes on one machine,
the same held-out figures within a few per cent on another CPU, whose float kernels give other weights).
"""

from __future__ import annotations

import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

from harness.biasnet.dataset import XI_DEFAULT, build_samples
from harness.biasnet.distill import DistillConfig
from harness.biasnet.export import DEFAULT_HEADER, DEFAULT_NPZ, export_c
from harness.biasnet.network import BiasModel, BiasNetwork
from harness.biasnet.registry import RECORDED_MODELS, SUMMARY, kind_name
from harness.biasnet.recipes import (FIRST_EVAL_SEED, STD_HEAD_RECIPE, SimRecipe, cf_usd_heldout_files,
                                     cf_usd_lever_arms, cf_usd_shelf_files, cf_usd_train_files,
                                     load_cf_usd_calibrated, rcv_heldout_dirs,
                                     rcv_train_dirs, util_heldout_files, util_train_files)
from harness.biasnet.train import TrainConfig
from harness.biasnet.uncertainty import StdHeadConfig, with_std_head
from harness.flight.loaders import load_recordings
from harness.biasnet.workflow import compare, distill_dict, distill_kind, train_kind
from harness.errors import UsageError
from harness.flight.data import Flight
from harness.paths import REPO_ROOT

MODELS_DIR = DEFAULT_NPZ.parent

#: The networks trained on the recordings are distilled from this many, network k validated on trial /
#: sequence k of the training data: on the held-out trial 5 and sequence 5 better and steadier over seeds
#: than one network validated on flights its seed draws (docs/bias-network.md, "Distilled ensemble").
RECORDED_TEACHERS = 4


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _train_cfg(quick: bool, max_epochs: int) -> TrainConfig:
    """Training ends by early stopping (or max_epochs), never by wall time: the shipped weights are the
    same on one machine (not bit for bit across CPUs). The time budget only bounds the --quick smoke run."""
    if quick:
        return TrainConfig(max_epochs=4, patience=8, time_budget_s=20.0)
    # Batch 512, not the default 1024: twice the steps per epoch, which the small recorded sets (UTIL,
    # rcv_twr) need to beat the baselines; the simulated sets are indifferent.
    return TrainConfig(max_epochs=max_epochs, patience=12, batch_size=512)


#: Obstacle arena: blocked links are delayed by 0.15 m + exp(0.15 m), with the multipath and the LOS bias up
#: to ~1 m in all; Xi = 0.7 m (the paper's outlier bound) would cut the exponential tail off and teach the
#: network a mean ~0.02 m short of the delay it has to remove (measured on held-out circles in that arena).
NLOS_XI = 1.0


def build_sim(quick: bool, profile: str = "los") -> dict[str, Any]:
    out: dict[str, Any] = {}
    nets = {}
    meta: dict[str, Any] = {}
    xi = NLOS_XI if profile == "nlos" else XI_DEFAULT
    for mode in ("twr", "tdoa"):
        recipe = SimRecipe(mode=mode, flights=4 if quick else 24, duration_s=30.0 if quick else 120.0,
                           spins=1 if quick else 4, profile=profile)
        t0 = time.perf_counter()
        flights = recipe.build()
        sim_s = time.perf_counter() - t0
        net, report, samples = train_kind(flights, None, _train_cfg(quick, 80 if profile == "los" else 160),
                                          f"sim {profile} {mode}", xi=xi)
        if profile == "los":  # the compiled-in network: its std head for the NN_STD stage
            net, meta[f"{mode}_std_head"] = _default_std_head(net, recipe, quick, xi)
        nets[mode] = net
        from harness.flight.scenarios import scenario_flight
        extra = {"radius": 1.5} if profile == "nlos" else {}  # the 2 m circle crosses a box of that arena
        test = [scenario_flight(name, mode=mode, duration_s=70.0, seed=FIRST_EVAL_SEED + k, profile=profile,
                                **(extra if name.startswith("circle") else {}))
                for k, name in enumerate(("circle", "circle-z", "random", "spin"))]
        res = compare(BiasModel(**{mode: net}), test, flights, xi=xi)  # type: ignore[arg-type]
        meta[f"{mode}_trained_on"] = [f"sim:{mode}:{profile}:seeds {recipe.seed0}-{recipe.seed0 + recipe.flights - 1}"]
        meta[f"{mode}_xi"] = xi
        meta[f"{mode}_training"] = {"samples": report.n_train, "val_samples": report.n_val, "epochs": report.epochs,
                                    "seconds": round(report.seconds, 1), "simulate_seconds": round(sim_s, 1),
                                    "stopped_by": report.stopped_by}
        meta[f"{mode}_heldout"] = {k: res["methods"][k] | {"per_pair": None} for k in res["methods"]}
        out[mode] = {"training": meta[f"{mode}_training"],
                     "heldout": {k: _short(v) for k, v in res["methods"].items()},
                     "heldout_flights": res["test"]}
        if f"{mode}_std_head" in meta:
            out[mode]["std_head"] = meta[f"{mode}_std_head"] | {"heldout_calibration": res.get("std_calibration")}
        _log(f"sim {profile} {mode}: held-out RMSE {res['rmse_raw']:.4f} -> {res['rmse_corrected']:.4f} m "
             f"({100 * res['reduction']:.1f} %), trained in {report.seconds:.1f} s")
    name = "default-sim" if profile == "los" else f"{profile}-sim"
    model = BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name=name, meta=meta)
    if profile == "los":  # compiled in as q15: accuracy cost ~0 mm (docs/bias-network.md, quantize.py)
        model = model.quantized("q15", name=name)
    fname = DEFAULT_NPZ.name if profile == "los" else f"bias_model_{profile}.npz"
    npz = model.save(MODELS_DIR / fname) if not quick else model.save(MODELS_DIR / "quick" / fname)
    if not quick and profile == "los":  # only the LOS network is compiled into the firmware
        export_c(model, DEFAULT_HEADER)
    out["file"], out["hash"] = _repo_path(npz), model.hash_hex
    return out


def _default_std_head(net: BiasNetwork, train: SimRecipe, quick: bool, xi: float) -> tuple[BiasNetwork, dict[str, Any]]:
    """The network with one std per kind: the RMS of its corrected residual on STD_HEAD_RECIPE's flights, which
    neither its training (``train``) nor any evaluation used. Constant, not pose-dependent: on held-out simulated
    flights both give the same calibration and the same campaign figures (docs/bias-network.md): the simulator's
    residual has no pose-dependent spread to learn, and a constant cannot extrapolate wrongly."""
    recipe = replace(STD_HEAD_RECIPE, mode=train.mode, flights=1 if quick else STD_HEAD_RECIPE.flights,
                     duration_s=30.0 if quick else STD_HEAD_RECIPE.duration_s)
    if set(recipe.seeds()) & set(train.seeds()):
        raise UsageError(f"std head seeds {recipe.seeds()} overlap the training seeds {train.seeds()}")
    samples = build_samples(recipe.build(), net.layout, xi)
    model = with_std_head(BiasModel(**{train.mode: net}), train.mode, samples,  # type: ignore[arg-type]
                          StdHeadConfig(constant=True))
    head = model.meta[f"{train.mode}_std_head"]
    head["seeds"] = f"sim:{train.mode}:{recipe.profile}:seeds {recipe.seed0}-{recipe.seed0 + recipe.flights - 1}"
    fitted = model.network(train.mode)
    assert fitted is not None
    _log(f"sim {train.mode} std head (constant) on {head['seeds']}: {head['calibration']['std_rms']:.4f} m")
    return fitted, head


def _repo_path(path: Path) -> str:
    """Path as recorded in models.json: relative to the repository, not this machine's checkout."""
    return str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else str(path)


def _short(m: dict[str, Any]) -> dict[str, Any]:
    return {k: m[k] for k in ("n", "rmse_raw", "rmse_corrected", "mae_raw", "mae_corrected", "reduction", "floor",
                              "share_of_ceiling", "floor_unbiased", "share_of_ceiling_unbiased")}


#: key of the pooled held-out figure of the Crazyflie network (its four evaluation flights together)
CF_POOLED = "0425-traj3+8+13+18"


def _build_recorded(name: str, data: Path, train_paths: list[Path], test_paths: list[Path], layout: int,
                    quick: bool, kind: str, teachers: int = RECORDED_TEACHERS,
                    pooled: tuple[str, list[Path]] | None = None,
                    load: Callable[[list[Path]], list[Flight]] = load_recordings) -> dict[str, Any]:
    """Train (distilled from `teachers` networks) and evaluate on each of `test_paths`, and on `pooled`'s
    recordings together (label, paths) when given; `load` reads the recordings (the uSD logs: with their
    calibrated lever arm)."""
    if not train_paths or not test_paths:
        return {"skipped": "the shared recordings are not there"}
    train = load(train_paths[:2] if quick else train_paths)
    cfg = _train_cfg(quick, 300)
    extra: dict[str, Any] = {}
    if quick:  # a smoke test: two recordings may be one flight group, too few folds
        net, report, _ = train_kind(train, layout, cfg, name)
    else:
        dcfg = DistillConfig(teachers=teachers)
        net, dreport, _ = distill_kind(train, layout, cfg, dcfg, name)
        assert dreport.student is not None
        report, extra = dreport.student, {"distilled": distill_dict(dreport, dcfg)}
    # relative to the data folder: the file says what it was trained on, not where this machine keeps it
    model = BiasModel(**{kind: net}, name=name,  # type: ignore[arg-type]
                      meta={f"{kind}_trained_on": [str(p.relative_to(data)) if p.is_relative_to(data) else str(p)
                                                   for p in (train_paths[:2] if quick else train_paths)],
                            f"{kind}_training": {"samples": report.n_train, "val_samples": report.n_val,
                                                 "epochs": report.epochs, "seconds": round(report.seconds, 1)}
                            | extra})
    results = {}
    groups = [(p.name if p.is_file() else p.parent.name + "/" + p.name, [p]) for p in test_paths]
    for label, paths in groups + ([pooled] if pooled and pooled[1] else []):
        res = compare(model, load(paths), train)
        results[label] = {k: _short(v) for k, v in res["methods"].items()}
        _log(f"{name} on {label}: " + ", ".join(f"{k} {100 * v['reduction']:.1f} %" for k, v in res["methods"].items()))
    model.meta[f"{kind}_heldout"] = results
    path = model.save((MODELS_DIR / "quick" if quick else MODELS_DIR) / f"{name}.npz")
    return {"file": _repo_path(path), "hash": model.hash_hex, "training": model.meta[f"{kind}_training"],
            "heldout": results}


def build_shipped_models(data: Path, quick: bool = False, only: str | None = None,
                         write_summary: bool = True) -> dict[str, Any]:
    """Train (and evaluate) the networks into firmware_sim/models/. The networks trained on ../shared/data
    (util_tdoa_pos.npz, rcv_twr.npz, cf_tdoa_pose.npz) are build products, not committed; write_summary=False builds them
    without touching the committed models.json (`make campaign` does that when they are missing)."""
    summary: dict[str, Any] = {"command": "make models" if not quick else "uwb-hil models --quick",
                               "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
                               "python": platform.python_version()}
    if only in (None, "sim"):
        summary["sim"] = build_sim(quick)
    if only in (None, "nlos"):
        summary["sim_nlos"] = build_sim(quick, profile="nlos")
    util, rcv = RECORDED_MODELS["util"], RECORDED_MODELS["rcv_twr"]
    if only in (None, "util"):
        summary[util.name] = _build_recorded(util.name, data, util_train_files(data), util_heldout_files(data),
                                             util.layout, quick, kind_name(util.kind))
    if only in (None, "rcv"):
        summary[rcv.name] = _build_recorded(rcv.name, data, rcv_train_dirs(data), rcv_heldout_dirs(data),
                                            rcv.layout, quick, kind_name(rcv.kind))
    if only in (None, "cfusd"):
        cf, train = RECORDED_MODELS["cf_usd"], cf_usd_train_files(data)
        levers = cf_usd_lever_arms(data)
        summary[cf.name] = _build_recorded(cf.name, data, train, cf_usd_heldout_files(data) + cf_usd_shelf_files(data),
                                           cf.layout, quick, kind_name(cf.kind), teachers=max(2, len(train)),
                                           pooled=(CF_POOLED, cf_usd_heldout_files(data)),
                                           load=lambda paths: load_cf_usd_calibrated(paths, levers))
        if isinstance(summary[cf.name], dict) and levers:
            summary[cf.name]["lever_arms_m"] = {k: [round(v, 4) for v in arm] for k, arm in sorted(levers.items())}
    if not quick and write_summary:
        _merge_summary(summary)
    return summary


def _merge_summary(summary: dict[str, Any]) -> None:
    """Write the models built into models.json and keep its other entries (`--only X` refreshes X's entry). A
    network skipped for want of its recordings keeps its committed entry; nothing built: the file is untouched."""
    built = {k: v for k, v in summary.items() if isinstance(v, dict) and "skipped" not in v}
    if not built:
        return
    header = {k: v for k, v in summary.items() if not isinstance(v, dict)}   # command, machine, python
    old = json.loads(SUMMARY.read_text()) if SUMMARY.is_file() else {}
    SUMMARY.write_text(json.dumps(old | header | built, indent=2, default=float) + "\n")
