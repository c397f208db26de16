"""`uwb-hil tune`: parse, run the grid (harness/calibrate/tune.py), print the ranking, write the settings file."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from harness import options
from harness.calibrate.tune import GridAxis, grid_search, settings_toml, write_settings
from harness.config import PRESETS
from harness.errors import InputError
from harness.flight.data import FLIGHT_ABOVE_M
from harness.paths import output_path


def add_tune_parser(sub: Any) -> None:
    p = sub.add_parser("tune", help="pick estimator settings on training recordings by a grid search through the "
                                    "firmware's twin, for `run --set @FILE.toml`")
    p.add_argument("--recording", action="append", required=True, metavar="REC",
                   help="a recording with ground truth (repeatable); tune on training flights, evaluate on others")
    p.add_argument("--anchors", help="anchor file for the recordings (default: each recording's own)")
    options.add_recording_read_options(p)
    p.add_argument("--tof", action=argparse.BooleanOptionalAction, default=None,
                   help="Crazyflie uSD logs: fuse the flow deck's ToF ranger when the log has readings "
                        "(default: as `run`)")
    p.add_argument("--grid", action="append", required=True, metavar="FIELD=V1,V2,...",
                   help="a CONFIG field and the values to try (repeatable: every combination is tried)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE|@FILE.toml",
                   help="settings every combination starts from (as `run --set`)")
    p.add_argument("--stages", default="outlier", choices=sorted(PRESETS), help="the estimator stages replayed")
    p.add_argument("--uwb-only", action="store_true", help="the constant-velocity model, without the IMU")
    p.add_argument("--model", help="bias model (.npz) for stages with the network")
    p.add_argument("--flight-above", type=options.height_m, default=FLIGHT_ABOVE_M, metavar="Z",
                   help="score the flight phase only: truth above this height [m]")
    p.add_argument("--out", required=True, help="settings file to write (TOML)")
    p.add_argument("--force", action="store_true", help="use recordings that fail the plausibility checks")
    p.add_argument("--json", action="store_true", help="print every combination's outcome as JSON")
    p.set_defaults(func=cmd_tune)


def _model(args: argparse.Namespace) -> object | None:
    if "nn" not in args.stages.split("+"):
        if args.model:
            raise InputError(f"--model given but the stages {args.stages!r} do not use the network")
        return None
    if not args.model:
        raise InputError(f"the stages {args.stages!r} use the network: give --model")
    from harness.biasnet.network import BiasModel
    return BiasModel.load(Path(args.model))


def cmd_tune(args: argparse.Namespace) -> int:
    axes = [GridAxis.parse(g) for g in args.grid]
    output_path(args.out, "--out")                   # before the grid search, not after it
    model = _model(args)
    from harness.flight.formats.cf_usd_flight import TOF_DEFAULT
    from harness.flight.loaders import recordings_from_args
    flights = recordings_from_args(args, tof=TOF_DEFAULT if args.tof is None else args.tof)
    trials = grid_search(flights, axes, args.stages, args.set, args.flight_above, args.uwb_only, model,
                         log=lambda line: print(f"tune: {line}", file=sys.stderr))
    write_settings(Path(args.out), settings_toml(trials[0], args.recording, args.stages, args.set, len(trials)))
    if args.json:
        print(json.dumps([t.as_dict() for t in trials], indent=2))
        return 0
    names = [a.field for a in axes]
    print(" ".join(f"{n:>14}" for n in names) + "  mean RMSE [m]  worst [m]  resets")
    for t in trials:
        vals = dict(t.settings)
        print(" ".join(f"{vals[n]:>14g}" for n in names) +
              f"  {t.mean_rmse_m:>14.4f}  {max(t.rmse_m):>9.4f}  {sum(t.resets):>6d}")
    best = trials[0]
    if best.diverged:
        print(f"tune: every combination diverged on some recording; {args.out} holds the least bad")
        return 1
    print(f"best: {', '.join(f'{k}={v:g}' for k, v in best.settings)} (mean flight RMSE {best.mean_rmse_m:.4f} m "
          f"over {len(flights)} recording(s), in-sample); written to {args.out}")
    return 0
