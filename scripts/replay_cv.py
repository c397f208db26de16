"""Cross-validated filter settings for the UTIL UWB-only replays (docs/bias-network.md, "Filter settings,
cross-validated").

    python scripts/replay_cv_folds.py                      # fold networks (once, ~3 min)
    python scripts/replay_cv.py --grid proc_cv_acc=1,2,4 --grid std_tdoa=0.1,0.15,0.2 \\
        [--states 0.3:0.12,1:0.12] [--stages outlier+nn+states] [--json out.json]

Every training flight (const1/const2 trials 1-4, tdoa2 and tdoa3) is replayed UWB-only through the host
firmware built with the network that never trained on its trial (util_fold_trialK.npz), once per setting
of the grid (the cartesian product of the --grid CONFIG fields, --set FIELD=VALUE fixed besides; --states
TAU:STD pairs rebuild the firmware with those bias-state constants). Prints the position RMSE per flight and
the means per TDoA mode and overall; the best setting by the overall mean is named. Trial 5 is never read.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from harness.biasnet.network import BiasModel
from harness.device.registry import DeviceSpec
from harness.firmware_build import build_firmware
from harness.paths import FIRMWARE_BUILD_DIR, SHARED_DATA
from harness.run.single import run_one
from harness.run.source import RunSource
from harness.stream.streamer import Pacing

TRIALS = (1, 2, 3, 4)


@dataclass(frozen=True)
class Flight:
    trial: int
    path: Path

    @property
    def mode(self) -> str:
        return "tdoa3" if "tdoa3" in self.path.name else "tdoa2"

    @property
    def label(self) -> str:
        return re.sub(r"-extracted\.csv$", "", self.path.name)


def training_flights(data: Path, trials: tuple[int, ...] = TRIALS) -> list[Flight]:
    out = []
    for t in trials:
        for c in (1, 2):
            out += [Flight(t, p) for p in sorted((data / "util" / f"const{c}").glob(f"const{c}-trial{t}-tdoa*-extracted.csv"))]
    return out


def parse_grid(items: list[str]) -> list[dict[str, str]]:
    axes = []
    for item in items:
        name, _, values = item.partition("=")
        if not name or not values:
            raise SystemExit(f"--grid wants FIELD=V1,V2,..., got {item!r}")
        axes.append([(name, v) for v in values.split(",")])
    return [dict(c) for c in itertools.product(*axes)] if axes else [{}]


def firmware(model_path: Path, states: tuple[str, str] | None) -> tuple[Path, int]:
    model = BiasModel.load(model_path)
    if states is None:
        return build_firmware("host", model), model.hash
    tau, std = states
    # a separate build per (model, constants): the Makefile's DEFS reach the compiler, bias_states.h keeps
    # its defaults unless they are defined (the power-up firmware is untouched)
    bdir = FIRMWARE_BUILD_DIR / "replay_cv" / f"{model.hash_hex}_tau{tau}_std{std}"
    defs = f"DEFS=-DBIAS_ST_TAU_S={float(tau)!r}f -DBIAS_ST_STD={float(std)!r}f"
    return build_firmware("host", model, build_dir=bdir, make_vars=(defs,)), model.hash


def replay(flight: Flight, exe: Path, want_hash: int, model: Path, anchors: Path, stages: str,
           sets: list[str]) -> dict[str, float]:
    src = RunSource(recording=str(flight.path), anchors=str(anchors), stages=stages, uwb_only=True,
                    model=str(model), set=sets)
    summary = run_one(DeviceSpec(target="host", firmware=exe), want_hash, src, Pacing(mode="windowed"), 10.0)
    acc = summary["accuracy"]
    return {k: float(acc[k]) for k in ("rmse", "rmse_xy", "rmse_z")}


def mean(xs: list[float]) -> float:
    return sum(xs) / len(xs) if xs else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--folds", type=Path, default=Path("out/replay_cv"))
    ap.add_argument("--stages", default="outlier+nn+states")
    ap.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--states", default=None, help="TAU:STD,... bias-state constants to try (rebuilds)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--trials", default="1,2,3,4", help="training trials to replay (a subset of 1-4)")
    ap.add_argument("--fold-suffix", default="", help="fold networks util_fold_trialT{SUFFIX}.npz (e.g. _distilled)")
    args = ap.parse_args()
    trials = tuple(int(t) for t in args.trials.split(","))
    if not set(trials) <= set(TRIALS):
        print(f"--trials must be among {TRIALS}, got {trials}", file=sys.stderr)
        return 2
    flights = training_flights(args.data, trials)
    anchors = args.data / "util" / "anchors.csv"
    models = {t: args.folds / f"util_fold_trial{t}{args.fold_suffix}.npz" for t in trials}
    missing = [str(p) for p in models.values() if not p.is_file()]
    if missing or not flights:
        print(f"missing fold networks {missing} (python scripts/replay_cv_folds.py) or flights", file=sys.stderr)
        return 2
    states = [tuple(s.split(":")) for s in args.states.split(",")] if args.states else [None]
    rows = []
    for st in states:
        exes = {t: firmware(models[t], st) for t in trials}  # type: ignore[arg-type]
        for setting in parse_grid(args.grid):
            sets = list(args.set) + [f"{k}={v}" for k, v in setting.items()]
            acc = {f.label: replay(f, *exes[f.trial], models[f.trial], anchors, args.stages, sets) for f in flights}
            rmse = {k: a["rmse"] for k, a in acc.items()}
            by_mode = {m: mean([rmse[f.label] for f in flights if f.mode == m]) for m in ("tdoa2", "tdoa3")}
            row = {"setting": setting | ({"tau": st[0], "std": st[1]} if st else {}), "rmse": rmse, "accuracy": acc,
                   "mean_tdoa2": by_mode["tdoa2"], "mean_tdoa3": by_mode["tdoa3"], "mean": mean(list(rmse.values()))}
            rows.append(row)
            print(f"{json.dumps(row['setting'])}: tdoa2 {row['mean_tdoa2']:.4f} tdoa3 {row['mean_tdoa3']:.4f} "
                  f"all {row['mean']:.4f}", flush=True)
    best = min(rows, key=lambda r: r["mean"])
    print(f"best by the mean of {len(flights)} out-of-fold flights: {json.dumps(best['setting'])} {best['mean']:.4f}")
    for m in ("tdoa2", "tdoa3"):
        b = min(rows, key=lambda r: r[f"mean_{m}"])
        print(f"best on {m}: {json.dumps(b['setting'])} {b[f'mean_{m}']:.4f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"stages": args.stages, "set": args.set, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
