"""uwb-hil command line: run flights through a device, print accuracy and latency.

    uwb-hil run --mode tdoa --stages outlier+nn            # simulated circle on the host build of the firmware
    uwb-hil run --recording FILE --anchors anchors.csv     # a recorded flight
    uwb-hil run --port /dev/ttyACM0 ...                    # a real board
    uwb-hil demo                                           # TWR and TDoA x three configurations
    uwb-hil calibrate --out DIR                            # simulator vs real UWB error statistics
    uwb-hil campaign --out DIR                             # the paper's experiments, in parallel, resumable
    uwb-hil report DIR                                     # DIR/report.html, report.md, report.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from harness import cli_verdict, options
from harness.cli_run import (HelpFormatter, VersionAction, check_header_source, given_dests, show_warning,
                             subparser)
from harness.config import PRESETS
from harness.device_args import add_device_options, device_spec, labgrid_lease, model_device_spec
from harness.errors import (EXIT_BUG, EXIT_DEVICE, EXIT_INPUT, EXIT_PASS, EXIT_VERDICT, UsageError, UwbHilError,
                            report_failure)
from harness.flight.scenarios import SCENARIOS
from harness.report.phases import DEFAULT_FLIGHT_ABOVE_M
from harness.run.demo import DemoFlights, run_demo
from harness.run.single import checked_results_path, resume_one, run_one
from harness.run.source import RunSource
from harness.device.registry import DeviceSpec
from harness.stream.streamer import PACING_MODES, Pacing


# ------------------------------------------------------------------------------------------ output
def _progress_bar(total_label: str) -> tuple[Callable[[int, int], None], Callable[[], None]]:
    """A rich progress bar when stderr is a terminal; silent otherwise."""
    if not sys.stderr.isatty():
        return (lambda done, total: None), (lambda: None)
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn
    prog = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), transient=True)
    prog.start()
    task = prog.add_task(total_label, total=None)

    def update(done: int, total: int) -> None:
        prog.update(task, completed=done, total=total)

    return update, prog.stop


def _fmt(x: float, digits: int = 3) -> str:
    return "-" if x != x else f"{x:.{digits}f}"


def device_line(device: dict[str, Any] | None, stages: Any) -> str:
    """One line naming the device that ran: target, port, build id, model hash, stages."""
    d = device or {}
    return (f"device: target {d.get('target', '-')}, port {d.get('port') or '-'}"
            + (f" (USB serial {d['usb_serial']})" if d.get("usb_serial") else "")
            + f", build {d.get('build_id', '-')}, model {d.get('model_hash', '-')}, stages {stages}")


def _speed(summary: dict[str, Any]) -> str:
    """The replay's speed; a run resumed from its results file has no wall time of its own (NaN)."""
    x = summary.get("realtime_factor")
    if x is None or x != x:
        return "(speed not measured: resumed from a results file)"
    return f"at {x:.1f}x real time"


def print_run(summary: dict[str, Any]) -> None:
    print(device_line(summary.get("device"), summary.get("config")))
    acc = summary["accuracy"]
    comp = summary["compute"]
    rtt = summary["round_trip_us"]
    unit = summary["compute_unit"]
    print(f"flight {summary['flight']}: {summary['measurements']} measurements, {summary['results']} results, "
          f"{summary['refused']} refused, {summary['lost']} lost; {summary['pacing']} replay " + _speed(summary))
    if summary.get("auxiliary"):
        aux = summary["auxiliary"]
        print(f"  also fused: {aux['measurements']} {aux['kind']} measurements (not scored)")
    print(f"  position RMSE {_fmt(acc['rmse'])} m (xy {_fmt(acc['rmse_xy'])}, z {_fmt(acc['rmse_z'])}, "
          f"max {_fmt(acc['max_error'])}); accepted {acc['accepted']}, rejected kinematic "
          f"{acc['rejected_kinematic']}, chi2 {acc['rejected_chi2']}")
    print(f"  device compute [{unit}]: n {comp['n']}  p50 {_fmt(comp['p50'], 2)}  p90 {_fmt(comp['p90'], 2)}  "
          f"p99 {_fmt(comp['p99'], 2)}  max {_fmt(comp['max'], 2)}  over budget {comp['deadline_misses']}")
    print(f"  round trip [us]: n {rtt['n']}  p50 {_fmt(rtt['p50'], 1)}  p90 {_fmt(rtt['p90'], 1)}  "
          f"p99 {_fmt(rtt['p99'], 1)}  max {_fmt(rtt['max'], 1)}  " + cli_verdict.rtt_misses_text(rtt))
    cli_verdict.print_phases(summary)
    cli_verdict.print_health(summary)
    cal = summary.get("range_offset")
    if cal:
        print(f"  range offset: {cal['offset_m']:+.3f} m subtracted"
              + (f" (per anchor: {', '.join(f'{k} {v:+.3f}' for k, v in cal['per_anchor_m'].items())})"
                 if cal.get("per_anchor_m") else "")
              + f", fitted on {len(cal['fitted_on'])} flight(s) "
              + ("without this one (held out)" if cal.get("held_out") else "INCLUDING this one (not held out)"))
    if summary.get("radio"):
        from harness.report.radio import format_radio
        print(format_radio(summary["radio"]))


# ------------------------------------------------------------------------------------------ commands
#: options that `run --resume` takes from the results file's header and so refuses on its command line
_RESUME_FIXED = (*RunSource.keys(), "pacing", "window", "speed", "results", "overwrite")


def _refuse_resume_conflicts(args: argparse.Namespace) -> None:
    run_parser = subparser(build_parser(), "run")
    typed = given_dests(run_parser, getattr(args, "argv", ()))
    given = [k for k in _RESUME_FIXED if k in typed]
    if given:
        flags = ", ".join("--" + k.replace("_", "-") for k in given)
        raise UsageError(f"--resume {args.resume} takes the flight, configuration and pacing from the file's header; "
                         f"drop {flags} (or start a new run without --resume)")


def _refuse_unused_pacing(args: argparse.Namespace) -> None:
    """--window is windowed pacing's, --speed realtime pacing's: typed with another pacing they did nothing."""
    typed = given_dests(subparser(build_parser(), args.command), getattr(args, "argv", ()))
    for dest, mode in (("window", "windowed"), ("speed", "realtime")):
        if dest in typed and args.pacing != mode:
            raise UsageError(f"--{dest} applies to --pacing {mode}, not {args.pacing}: drop one of them")


def cmd_resume(args: argparse.Namespace) -> int:
    """Continue an interrupted run from its results file (see harness/stream/resume.py)."""
    _refuse_resume_conflicts(args)
    path = Path(args.resume)

    def spec_for(src: RunSource) -> tuple[DeviceSpec, int | None]:
        return model_device_spec(argparse.Namespace(**{**vars(args), "model": src.model}))

    def check_source(src: Mapping[str, Any], where: str) -> None:
        check_header_source(subparser(build_parser(), "run"), RunSource.keys(), src, where)

    summary = resume_one(path, spec_for, args.timeout, progress=_progress_bar, check_source=check_source)
    info = summary["resume"]
    if info.get("partial_line_bytes_dropped"):
        print(f"uwb-hil: {path}: cut a partial last line ({info['partial_line_bytes_dropped']} bytes, written "
              "when the run was killed); its measurement was run again", file=sys.stderr)

    def text() -> None:
        print(f"resumed {path} at measurement {info['resumed_at']}: replayed {info['replayed']} "
              f"(identical to the record), appended {info['appended']}")
        print_run(summary)
    return cli_verdict.finish(args, summary, [summary], cli_verdict.criteria_from(args), text)


def cmd_run(args: argparse.Namespace) -> int:
    if getattr(args, "resume", None):
        return cmd_resume(args)
    criteria = cli_verdict.criteria_from(args)
    src = RunSource.from_mapping(vars(args))
    src.check_options_apply()
    _refuse_unused_pacing(args)
    inputs = [src.recording, src.anchors, src.range_offset, src.model, getattr(args, "criteria", None),
              *(x for x in src.set if x.startswith("@"))]
    results = checked_results_path(args.results, args.overwrite, inputs)
    spec, want_hash = model_device_spec(args)
    summary = run_one(spec, want_hash, src, Pacing(mode=args.pacing, window=args.window, speed=args.speed),
                      args.timeout, results=results, overwrite=args.overwrite, progress=_progress_bar)
    for warning in summary.get("warnings", []):
        print(f"uwb-hil: warning: {warning}", file=sys.stderr)
    return cli_verdict.finish(args, summary, [summary], criteria, lambda: print_run(summary))


def cmd_ports(args: argparse.Namespace) -> int:
    from harness.link.ports import ENV_PORT, default_port, list_ports
    ports = list_ports()
    if args.json:
        print(json.dumps({"ports": [p.as_dict() for p in ports], "default": default_port()}, indent=2))
        return 0
    if not ports:
        print("no serial ports found on this machine")
    for p in ports:
        print(f"{p.device:20s} {p.description:40s} serial {p.serial_number or '-'}")
    print(f"default port (${ENV_PORT}): {default_port() or 'not set'}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    criteria = cli_verdict.criteria_from(args)
    _refuse_unused_pacing(args)
    device, rows = run_demo(device_spec(args), DemoFlights(args.scenario, args.duration, args.seed),
                            Pacing(mode=args.pacing, window=args.window, speed=args.speed), args.timeout)
    payload = {"device": device, "runs": rows}
    return cli_verdict.finish(args, payload, rows, criteria, lambda: _print_demo_table(rows, device))


def _print_demo_table(rows: list[dict[str, Any]], device: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table
    unit = rows[0]["compute_unit"] if rows else "us"
    print(device_line(device, "per row") + f", firmware {device.get('firmware', '-')}")
    table = Table(title="uwb-hil demo")
    for col in ("mode", "config", "RMSE [m]", "accepted", "rej. kin", "rej. chi2", f"compute p50 [{unit}]",
                f"compute p99 [{unit}]", "RTT p50 [us]", "RTT p99 [us]", "lost", "speed"):
        table.add_column(col, justify="right" if col not in ("mode", "config") else "left")
    for s in rows:
        a, c, r = s["accuracy"], s["compute"], s["round_trip_us"]
        table.add_row(s["mode"], s["config"], _fmt(a["rmse"]), str(a["accepted"]), str(a["rejected_kinematic"]),
                      str(a["rejected_chi2"]), _fmt(c["p50"], 2), _fmt(c["p99"], 2), _fmt(r["p50"], 0),
                      _fmt(r["p99"], 0), str(s["lost"]), f"{_fmt(s['realtime_factor'], 0)}x")
    Console(width=160).print(table)


# ------------------------------------------------------------------------------------------ parser
#: the exit codes of every command (harness/errors.py), at the end of `uwb-hil --help`
EXIT_CODES_HELP = (f"exit codes: {EXIT_PASS} every check passed, {EXIT_VERDICT} the verdict failed, {EXIT_INPUT} usage "
                   f"or input error, {EXIT_DEVICE} device or link failure,\n            {EXIT_BUG} a bug in uwb-hil "
                   "(stderr names the file holding its traceback), 130 interrupted")


def _add_flight_options(p: argparse.ArgumentParser, recorded: bool = True) -> None:
    """Simulated-flight options; with `recorded`, also those of a recorded flight (not for `demo`, which
    flies its own simulated TWR and TDoA flights)."""
    g = p.add_argument_group("flight")
    g.add_argument("--scenario", default="circle", help=f"simulated flight: {', '.join(SCENARIOS)}")
    if recorded:
        g.add_argument("--mode", choices=("twr", "tdoa"), default="twr", help="UWB measurement type (simulation)")
    g.add_argument("--duration", type=options.sim_duration_s, default=30.0,
                   help=f"simulated flight length [s] (at most {options.MAX_SIM_DURATION_S:g})")
    g.add_argument("--seed", type=options.non_negative_int, default=1, help="seed of the simulated flight's noise")
    if not recorded:
        return
    g.add_argument("--recording", help="replay a recorded flight instead (UTIL CSV, rcv_twr sequence, Crazyflie "
                                       "uSD log, .npz)")
    g.add_argument("--anchors", help="anchor file for the recording (UTIL anchors.csv, survey .npz, YAML)")
    options.add_recording_read_options(g)
    g.add_argument("--tof", action=argparse.BooleanOptionalAction, default=None,
                   help="Crazyflie uSD logs: fuse the flow deck's downward ToF ranger (estTOF) with the UWB "
                        "measurements (default: on when the log has ToF readings, as a Crazyflie with a flow deck; "
                        "the paper's system had none: --no-tof; docs/real-flights.md)")
    g.add_argument("--range-offset", metavar="FILE.json",
                   help="TWR range-offset calibration (antenna delay) subtracted from the ranges before they are "
                        "streamed; fit one on recordings with ground truth: `uwb-hil range-offset`")
    g.add_argument("--constellation", type=options.non_negative_int, metavar="N",
                   help="constellation of a multi-constellation anchors.csv (default: constN in the file name)")
    g.add_argument("--force", action="store_true",
                   help="replay a recording that fails the plausibility checks (units, anchor geometry, gross "
                        "errors, time overlap), or with a network that needs an attitude the replay lacks")
    g.add_argument("--flight-above", type=options.number(float, -1000.0, 1000.0, unit=" m"),
                   default=DEFAULT_FLIGHT_ABOVE_M, metavar="Z",
                   help="a measurement whose true tag height is below Z [m] (anchors' frame) is in the ground phase: "
                        "reported apart, and --max-rmse / --max-rmse-xy judge the flight phase (default "
                        f"{DEFAULT_FLIGHT_ABOVE_M:g}; a run that never goes below has one phase)")


def _add_pacing_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("pacing")
    g.add_argument("--pacing", choices=PACING_MODES, default="windowed",
                   help="windowed (up to --window measurements in flight), lockstep (one at a time) or "
                        "realtime (at the flight's own time stamps x --speed)")
    g.add_argument("--window", type=options.window, default=Pacing.window, help="measurements in flight (windowed, 1..1024)")
    g.add_argument("--speed", type=options.speed, default=1.0, help="real-time pacing speed factor, 0.01 to 1e6 (default %(default)s)")


def _add_stage_options(p: argparse.ArgumentParser) -> None:
    """The estimator's stages and settings, and the radio level (`run`)."""
    g = p.add_argument_group("stages", "what the estimator runs: stages, settings, model, radio level")
    g.add_argument("--stages", choices=tuple(PRESETS), default="outlier+nn",
                   help="none | outlier (kinematic + chi-square gates) | outlier+nn (plus bias network) | "
                        "...+states (plus per-anchor bias states, docs/bias-network.md)")
    g.add_argument("--uwb-only", action="store_true", help="ignore the IMU (constant-velocity model)")
    g.add_argument("--model", help="bias model (.npz) the device must carry; the host build is built "
                                   "with it, any other device is refused if its HELLO reports another model")
    g.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override an estimator setting, e.g. --set std_tdoa=0.1 (repeatable); --set @FILE.toml "
                        "takes the [settings] table of a settings file (harness/settings/)")
    g.add_argument("--radio", choices=("tdoa2", "tdoa3"), default=None,
                   help="LPS radio level: stream the anchor packets the tag's radio receives (simulated by the "
                        "radio simulator, or synthesised from a TDoA recording's differences) and let the "
                        "firmware's TDoA engine form the measurements; the summary gains a radio section")
    g.add_argument("--radio-trace", metavar="FILE", default=None,
                   help="LPS radio level from recorded anchor packets: a CSV of t_rx_ticks,sender,packet_hex "
                        "(docs/radio.md) replayed to the firmware's TDoA engine; the flight (--mode tdoa or a "
                        "recording) gives anchors, truth and IMU")
    g.add_argument("--radio-loss", type=float, default=0.0, metavar="P",
                   help="with --radio on a simulated flight: probability that the tag misses a packet [0, 1)")


def _add_output_options(p: argparse.ArgumentParser) -> None:
    """Where the results go (`run`)."""
    g = p.add_argument_group("output", "what is written and printed")
    g.add_argument("--results", help="write per-measurement results as JSON Lines here (locked while written; "
                                     "a file holding an unfinished run is kept unless --overwrite; never an "
                                     "input of the run)")
    g.add_argument("--overwrite", action="store_true",
                   help="let --results replace a file that holds an unfinished (resumable) run")
    g.add_argument("--resume", metavar="RESULTS.jsonl",
                   help="continue an interrupted run recorded in this results file (same flight, config and "
                        "pacing from its header; new results appended; summary over the whole flight)")
    g.add_argument("--json", action="store_true", help="print the summary (with its verdict) as JSON")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="uwb-hil", description=__doc__, epilog=EXIT_CODES_HELP,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action=VersionAction,
                    help="print the package, protocol and firmware versions and exit")
    sub = ap.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="stream one flight through a device", formatter_class=HelpFormatter)
    _add_flight_options(run)
    _add_pacing_options(run)
    add_device_options(run)
    _add_stage_options(run)
    _add_output_options(run)
    cli_verdict.add_planar_options(run)
    cli_verdict.add_verdict_options(run)
    run.set_defaults(func=cmd_run)
    demo = sub.add_parser("demo", help="TWR and TDoA flights in three configurations, one table",
                          formatter_class=HelpFormatter)
    _add_flight_options(demo, recorded=False)
    _add_pacing_options(demo)
    add_device_options(demo)
    demo.add_argument_group("output").add_argument("--json", action="store_true",
                                                   help="print every run's summary as JSON")
    cli_verdict.add_verdict_options(demo)
    demo.set_defaults(func=cmd_demo, duration=20.0)
    ports = sub.add_parser("ports", help="serial ports of this machine: device, description, USB serial number")
    ports.add_argument("--json", action="store_true", help="print the ports as JSON")
    ports.set_defaults(func=cmd_ports)
    from harness.closedloop.cli import add_fly_parser
    add_fly_parser(sub)
    from harness.calibrate.cli import add_parser as add_calibrate_parser
    add_calibrate_parser(sub)
    from harness.calibrate.cli import add_lever_arm_parser, add_range_offset_parser
    add_range_offset_parser(sub)
    add_lever_arm_parser(sub)
    from harness.calibrate.tune_cli import add_tune_parser
    add_tune_parser(sub)
    from harness.campaign import cli as campaign_cli
    from harness.report import cli as report_cli
    campaign_cli.add_parser(sub)
    report_cli.add_parser(sub)
    from harness.biasnet.cli import add_commands as add_biasnet_commands
    add_biasnet_commands(sub)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    import warnings
    with warnings.catch_warnings():      # restored afterwards: main() may be called in-process
        warnings.showwarning = show_warning
        return _main(list(sys.argv[1:] if argv is None else argv))


def _main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    args.argv = argv          # what was typed: options are compared as given or not, never with their default
    try:
        with labgrid_lease(args):          # --labgrid-place: the place held while the command runs
            code = int(args.func(args))
        sys.stdout.flush()       # a closed pipe shows here, inside the handlers below, not at exit
        return code
    except UwbHilError as exc:
        return report_failure(exc, "uwb-hil")    # 3: device or link failure, 2: usage or input
    except KeyboardInterrupt:
        print("uwb-hil: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # whoever read stdout stopped (`uwb-hil run | head`): end quietly, as a tool killed by SIGPIPE would
        # (128 + 13); stdout goes to /dev/null so the interpreter's final flush cannot fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:
        # a file the command writes (--out DIR, a full disk, no permission): the user's to fix, not a crash;
        # device and link failures arrive as LinkError / DeviceError above (exit 3)
        return report_failure(exc, "uwb-hil")
    except Exception as exc:  # noqa: BLE001 - anything else is a bug: exit 4, its traceback in a file
        return report_failure(exc, "uwb-hil")


if __name__ == "__main__":
    sys.exit(main())
