"""`uwb-hil fly`: closed-loop campaigns (modes x missions x configurations x seeds) through one device.

    uwb-hil fly                                   # TWR + TDoA, circle + circle-z, 3 configurations, 10 seeds
    uwb-hil fly --mode tdoa --mission circle --config outlier+nn --seeds 3 --json
    uwb-hil fly --port /dev/ttyACM0 --baud 1000000 --pacing realtime   # a real board at flight speed
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from harness.closedloop.fly import FlySpec, fly_on_device
from harness.closedloop.cosim import PACINGS, LoopConfig
from harness.closedloop.mission import MISSIONS
from harness.closedloop.sensors import NOISE_KINDS
from harness.cli_run import RawDescriptionHelpFormatter
from harness.cli_verdict import criteria_from
from harness.config import PRESETS, config_with
from harness.device_args import add_device_options, model_device_spec
from harness.errors import UsageError
from harness.flight.measurement_errors import PROFILES
from harness.paths import output_path
from harness.report import jsonsafe
from harness.report.verdict import FLY_CRITERIA, fly_verdict


# ------------------------------------------------------------------------------------------ output
def _fmt(x: float, d: int = 3) -> str:
    return "-" if x is None or x != x else f"{x:.{d}f}"


def table_rows(result: dict[str, Any]) -> list[list[str]]:
    rows = []
    for c in result["cells"]:
        rows.append([c["mode"], c["mission"], c["config"], f"{c['takeoff_success']}/{c['flights']}",
                     f"{c['completed']}/{c['flights']}",
                     f"{_fmt(c['tracking_rmse_mean'])} +- {_fmt(c['tracking_rmse_std'])}",
                     _fmt(c["tracking_rmse_max"]),
                     f"{_fmt(c['estimation_rmse_mean'])} +- {_fmt(c['estimation_rmse_std'])}"])
    return rows


HEADERS = ["mode", "mission", "config", "take-off", "completed", "tracking RMSE [m]", "worst seed [m]",
           "estimation RMSE [m]"]


def markdown_table(result: dict[str, Any]) -> str:
    lines = ["| " + " | ".join(HEADERS) + " |", "|" + "---|" * len(HEADERS)]
    lines += ["| " + " | ".join(r) + " |" for r in table_rows(result)]
    return "\n".join(lines)


def print_table(result: dict[str, Any], device: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table
    spec = result["spec"]
    table = Table(title=f"uwb-hil fly - {len(spec['seeds'])} seeds, profile {spec['profile']}, device "
                        f"{device.get('target', '?')} model {device.get('model_hash', '?')}")
    for h in HEADERS:
        table.add_column(h, justify="left" if h in ("mode", "mission", "config") else "right")
    for r in table_rows(result):
        table.add_row(*r)
    Console(width=160).print(table)
    for c in result["cells"]:
        for why in c["takeoff_failures"]:
            print(f"  {c['mode']} {c['mission']} {c['config']}: take-off failed: {why}")


# ------------------------------------------------------------------------------------------- CLI
def _csv(choices: Sequence[str], what: str) -> Callable[[str], tuple[str, ...]]:
    def parse(text: str) -> tuple[str, ...]:
        items = tuple(s.strip() for s in text.split(",") if s.strip())
        bad = [s for s in items if s not in choices]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"{what} must be a comma list of {', '.join(choices)}; got {text!r}")
        return items
    return parse


def add_fly_parser(sub: Any) -> None:
    p = sub.add_parser("fly", help="closed loop: the device flies a simulated Crazyflie on UWB alone",
                       description=__doc__, formatter_class=RawDescriptionHelpFormatter)
    d = FlySpec()      # the defaults
    p.add_argument("--mode", type=_csv(("twr", "tdoa"), "--mode"), default=d.modes,
                   help="twr, tdoa or both (comma list; default both)")
    p.add_argument("--mission", type=_csv(MISSIONS, "--mission"), default=d.missions,
                   help=f"comma list of {', '.join(MISSIONS)} (default {','.join(d.missions)})")
    p.add_argument("--config", type=_csv(tuple(PRESETS), "--config"), default=d.configs,
                   help=f"comma list of {', '.join(PRESETS)} (default {', '.join(d.configs)})")
    p.add_argument("--seeds", type=int, default=len(d.seeds), help="flights per cell (seeds seed0 .. seed0+N-1)")
    p.add_argument("--seed0", type=int, default=d.seeds[0], help="seed of the first flight")
    p.add_argument("--laps", type=float, default=d.laps, help="circle laps (2 m radius at 0.375 m/s: 33.5 s each)")
    p.add_argument("--hover-s", type=float, default=d.hover_s, help="length of the hover mission's main segment [s]")
    p.add_argument("--radius", type=float, default=d.radius, help="circle radius [m] (the simulator's)")
    p.add_argument("--height", type=float, default=d.height, help="circle / hover height [m]")
    p.add_argument("--profile", choices=PROFILES, default=d.profile, help="simulator error profile")
    p.add_argument("--noise", choices=NOISE_KINDS, default=d.noise, help="simulated UWB error model")
    p.add_argument("--mass", type=float, default=d.mass,
                   help="simulated vehicle mass [kg] (what the controller assumes)")
    p.add_argument("--pacing", choices=PACINGS, default=d.loop.pacing,
                   help="lockstep (deterministic, as fast as possible) or realtime (flight speed, for boards)")
    p.add_argument("--speed", type=float, default=d.loop.speed, help="realtime pacing speed factor")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override an estimator setting for every flight, e.g. --set std_tdoa=0.25 (repeatable; "
                        "as `uwb-hil run --set`)")
    p.add_argument("--imu-every", type=int, default=d.loop.imu_every,
                   help="physics steps (2 ms) per IMU frame (averaged)")
    p.add_argument("--model", help="bias model (.npz) for outlier+nn: the host build is built with it; "
                                   "any other device must report its hash (default: the compiled-in model)")
    p.add_argument("--max-rmse", type=float, default=None, metavar="X",
                   help="verdict: worst seed's tracking RMSE per cell [m] (take-off and completion always checked; "
                        "exit 1 if a check fails)")
    p.add_argument("--criteria", metavar="FILE.toml",
                   help="criteria from a TOML file (as `uwb-hil run --criteria`; fly judges max_rmse only, other "
                        "criteria are refused as not applicable); --max-rmse wins over the file")
    p.add_argument("--json", action="store_true", help="print everything (incl. per-flight figures) as JSON")
    p.add_argument("--out", help="also write the JSON result to this file")
    p.add_argument("--markdown", action="store_true", help="print the table as Markdown (for docs)")
    p.add_argument("--quiet", action="store_true", help="no per-flight progress lines on stderr")
    add_device_options(p)
    p.set_defaults(func=cmd_fly)


def cmd_fly(args: argparse.Namespace) -> int:
    if args.seeds < 1:
        raise UsageError("--seeds must be >= 1")
    criteria = criteria_from(args, FLY_CRITERIA, "uwb-hil fly")    # refused (exit 2) before any flight
    if args.out:
        output_path(args.out, "--out")
    loop = LoopConfig(pacing=args.pacing, speed=args.speed, timeout_s=args.timeout, imu_every=args.imu_every)
    spec = FlySpec(modes=args.mode, missions=args.mission, configs=args.config,
                   seeds=tuple(range(args.seed0, args.seed0 + args.seeds)), laps=args.laps,
                   hover_s=args.hover_s, radius=args.radius, height=args.height, profile=args.profile,
                   noise=args.noise, mass=args.mass, loop=loop, estimator=config_with(args.set))
    progress = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    device_spec, want_hash = model_device_spec(args)
    result = fly_on_device(device_spec, want_hash, spec, progress)
    result["command"] = "uwb-hil " + " ".join(sys.argv[1:]) if sys.argv and sys.argv[0].endswith("uwb-hil") else None
    verdict = fly_verdict(result, criteria)
    result["verdict"] = verdict.as_dict()
    if args.out:
        Path(args.out).write_text(jsonsafe.dumps(result, indent=1))
    if args.json:
        print(jsonsafe.dumps(result, indent=1))
    elif args.markdown:
        print(markdown_table(result))
    else:
        print_table(result, result["device"])
        print(f"verdict: {'PASS' if verdict.passed else 'FAIL'} ({len(verdict.checks)} checks)")
    if not verdict.passed:
        print(f"uwb-hil: verdict failed: {verdict.reason()}", file=sys.stderr)
        return 1
    return 0
