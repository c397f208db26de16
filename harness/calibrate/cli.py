"""`uwb-hil calibrate`: parses the options, prints the statistics (harness/calibrate/compare.py); and
`uwb-hil range-offset`: fits a TWR range-offset calibration (antenna delay) on recordings with ground truth and
writes it for `uwb-hil run --range-offset FILE` (harness/flight/range_offset.py); `uwb-hil lever-arm`: fits the
tag's lever arm (antenna phase centre, body frame) for `--lever-arm FILE` (harness/flight/lever_arm.py)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Callable

from harness import options
from harness.calibrate.compare import calibrate
from harness.calibrate.plots import write_plots
from harness.calibrate.stats import STATS_KEYS
from harness.errors import UsageError
from harness.flight.data import FLIGHT_ABOVE_M
from harness.report import jsonsafe
from harness.paths import output_path, shared_data_dir


def _f(x: float, d: int = 3) -> str:
    return "-" if x != x else f"{x:.{d}f}"


def format_report(res: dict[str, Any]) -> str:
    lines = []
    for g in res["util"]:
        lines.append(f"{g['group']}: {len(g['real_files'])} real trials vs {len(g['sim_flights'])} simulated "
                     f"({g['mode']}, profile {g['profile']}); mean over trials [min..max]")
        lines.append(f"  {'statistic':<14}{'real':>26}{'simulated':>26}{'sim/real':>10}")
        for key in STATS_KEYS[1:]:
            r, s = g["real"][key], g["sim"][key]
            d = 4 if key.startswith("frac") else 3
            ratio = s["mean"] / r["mean"] if r["mean"] not in (0.0,) and r["mean"] == r["mean"] else math.nan
            lines.append(f"  {key:<14}{_f(r['mean'], d):>10} [{_f(r['min'], d)}..{_f(r['max'], d)}]"
                         f"{_f(s['mean'], d):>10} [{_f(s['min'], d)}..{_f(s['max'], d)}]"
                         f"{_f(ratio, 2) if key in ('std', 'pair_spread') else '':>10}")
        lines.append("")
    if "twr" in res:
        st = res["twr"]["stats"]
        lines.append("rcv_twr TWR (5 sequences, 4 anchors; simulator error model at the recorded poses)")
        lines.append(f"  {'statistic':<14}{'real':>10}{'simulated':>12}")
        for key in ("mean", "median", "std", "centred_std", "frac_gt_0.3", "frac_gt_1", "pair_spread", "noise"):
            d = 4 if key.startswith("frac") else 3
            lines.append(f"  {key:<14}{_f(st['real'][key], d):>10}{_f(st['sim'][key], d):>12}")
        lines.append("  pose dependence (std of binned medians of the centred error) [m]:")
        for key, d in res["twr"]["dependence"].items():
            lines.append(f"    {key:<10} real {_f(d['amplitude']['real'])}  sim {_f(d['amplitude']['sim'])}   "
                         "medians real/sim by bin: " + " ".join(
                             f"{_f(a, 2)}/{_f(b, 2)}" for a, b in zip(d["real_median"], d["sim_median"])))
    return "\n".join(lines)


def add_parser(sub: Any) -> None:
    p = sub.add_parser("calibrate", help="simulated vs real UWB error statistics (UTIL TDoA, rcv_twr TWR)")
    p.add_argument("--data", help="real data directory (default ../shared/data or $UWB_HIL_DATA)")
    p.add_argument("--trials", type=int, default=5, help="simulated trials per group")
    p.add_argument("--duration", type=options.sim_duration_s, default=60.0, help="simulated trial length [s]")
    p.add_argument("--out", help="directory for the PNG plots")
    p.add_argument("--no-twr", action="store_true", help="skip the rcv_twr TWR comparison")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    data = Path(args.data) if args.data else shared_data_dir()
    if args.trials < 1 or not args.duration > 20.0:
        raise UsageError("--trials must be >= 1 and --duration > 20 s (take-off and landing take 10 s)")
    if args.out:
        output_path(args.out, "--out", directory=True)
    res = calibrate(data, n_trials=args.trials, duration_s=args.duration, twr=not args.no_twr)
    links = res.pop("_links", None)
    if args.out:
        plots = write_plots(Path(args.out), links, res.get("twr", {}).get("dependence"), res["util"])
        res["plots"] = [str(p) for p in plots]
    if args.json:
        print(jsonsafe.dumps(res, indent=1))
    else:
        print(format_report(res))
        for p in res.get("plots", []):
            print(f"plot: {p}")
    return 0


# ------------------------------------------------------------------------------------ range-offset
def add_range_offset_parser(sub: Any) -> None:
    p = sub.add_parser("range-offset", help="fit a TWR range-offset calibration (antenna delay) on recordings "
                                            "with ground truth, for `run --range-offset`")
    _add_calibration_io(p, "a TWR recording with ground truth (repeatable: every range of every recording is "
                           "used); to evaluate, leave the flight you replay out")
    p.add_argument("--per-anchor", action="store_true",
                   help="also an offset per anchor id (on rcv_twr it does not carry over between sequences)")
    p.set_defaults(func=cmd_range_offset)


def _add_calibration_io(p: argparse.ArgumentParser, recording_help: str) -> None:
    """The inputs and outputs of a calibration command: recordings, anchors, reader options, --out, --json."""
    p.add_argument("--recording", action="append", required=True, metavar="REC", help=recording_help)
    p.add_argument("--anchors", help="anchor file for the recordings (default: each recording's own)")
    options.add_recording_read_options(p)
    p.add_argument("--out", required=True, help="calibration file to write (JSON)")
    p.add_argument("--force", action="store_true", help="use recordings that fail the plausibility checks")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")


def _saved_as_json(args: argparse.Namespace, cal: Any, save: Callable[[Any, Path], object]) -> bool:
    """Write the calibration to --out; with --json print it whole (True: nothing else to print)."""
    save(cal, Path(args.out))
    if args.json:
        print(json.dumps(cal.as_dict(), indent=2))
    return bool(args.json)


def cmd_range_offset(args: argparse.Namespace) -> int:
    from harness.flight.range_offset import fit_range_offset, save_range_offset
    from harness.flight.loaders import recordings_from_args
    output_path(args.out, "--out")
    flights = recordings_from_args(args)
    cal = fit_range_offset(flights, per_anchor=args.per_anchor)
    if _saved_as_json(args, cal, save_range_offset):
        return 0
    print(f"range offset {cal.offset_m:+.4f} m (median range - true range over {cal.measurements} ranges of "
          f"{len(flights)} flight(s): {', '.join(cal.fitted_on)})")
    for k, v in sorted(cal.per_anchor_m.items()):
        print(f"  anchor {k}: {v:+.4f} m")
    print(f"written to {args.out}")
    return 0


# --------------------------------------------------------------------------------------- lever-arm
def add_lever_arm_parser(sub: Any) -> None:
    p = sub.add_parser("lever-arm", help="fit the UWB tag's lever arm (antenna phase centre in the body frame) on "
                                         "recordings with attitude, for `--lever-arm FILE`")
    _add_calibration_io(p, "a recording with ground-truth attitude (repeatable); to evaluate, leave the flight "
                           "you replay out")
    p.add_argument("--flight-above", type=options.height_m, default=FLIGHT_ABOVE_M, metavar="Z",
                   help="use measurements with the truth above this height [m] (the ground phase is NLOS)")
    p.set_defaults(func=cmd_lever_arm)


def cmd_lever_arm(args: argparse.Namespace) -> int:
    from harness.flight.lever_arm import fit_lever_arm, save_lever_arm
    from harness.flight.loaders import recordings_from_args
    output_path(args.out, "--out")
    flights = recordings_from_args(args)
    fit = fit_lever_arm(flights, flight_above=args.flight_above)
    if _saved_as_json(args, fit, save_lever_arm):
        return 0
    vec = ", ".join(f"{v:+.4f}" for v in fit.lever_arm_m)
    print(f"lever arm ({vec}) m, body frame: the assumed one corrected by "
          f"({', '.join(f'{v:+.4f}' for v in fit.correction_m)}) m over {fit.measurements} in-flight measurements "
          f"of {len(flights)} flight(s)")
    for name, corr in fit.per_flight_m.items():
        print(f"  {name}: ({', '.join(f'{v:+.4f}' for v in corr)})")
    print(f"written to {args.out}")
    return 0
