"""`uwb-hil campaign`: plan, run (in parallel, resumable) and optionally report the paper's experiments."""

from __future__ import annotations

import argparse
import os
import sys
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

from harness.campaign.boards import BoardExecutor, note_boards_in_verdict
from harness.campaign.cluster import scheduler_from
from harness.campaign.plan import CONFIGS, FIRST_EVAL_SEED, MODES, TRAJECTORIES, CampaignOptions, parse_shard
from harness.campaign.runner import CampaignOutcome, ExecOptions, GroupExecutor, plan_and_run
from harness.campaign.store import CampaignDir
from harness.campaign.verdict import BASELINE_CONFIG, check_judged, default_judged, judge_campaign
from harness.cli_verdict import add_verdict_options, criteria_from
from harness.device.board_list import boards_from_options, check_unique, load_board_list
from harness.device.registry import TARGET_CHOICES
from harness.device_args import add_labgrid_options
from harness.errors import EXIT_DEVICE, EXIT_PASS, EXIT_VERDICT, UsageError
from harness.options import DEFAULT_BAUD, baud
from harness.paths import DEFAULT_FIRMWARE, output_path, shared_data_dir
from harness.stream.streamer import PACING_MODES


#: set to 1 (e.g. on a CI machine without the shared data) to make --no-recorded the default
NO_RECORDED_ENV = "UWB_HIL_NO_RECORDED"


def _recorded(args: argparse.Namespace) -> bool:
    if args.recorded is not None:
        return bool(args.recorded)
    return os.environ.get(NO_RECORDED_ENV, "").strip() not in ("1", "true", "yes")


def _csv(text: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def add_parser(sub: Any) -> None:
    p = sub.add_parser("campaign", help="run the paper's experiments (simulated + recorded) in parallel",
                       description=f"Simulated {{{', '.join(MODES)}}} x {{{', '.join(CONFIGS)}}} x trajectories x "
                                   "seeds and held-out recorded flights, each run through the firmware on its own "
                                   "host build. Re-running the same command resumes (complete runs are skipped).")
    d, e = CampaignOptions(), ExecOptions()      # the defaults
    p.add_argument("--out", required=True, help="campaign directory (created; resumed if it exists)")
    p.add_argument("--seeds", type=int, default=d.seeds,
                   help="simulated flights per mode and trajectory (default %(default)s)")
    p.add_argument("--first-seed", type=int, default=d.first_seed,
                   help=f"first seed (default %(default)s; training uses seeds below {FIRST_EVAL_SEED}: keep >= "
                        f"{FIRST_EVAL_SEED} for unseen flights)")
    p.add_argument("--duration", type=float, default=d.duration_s,
                   help="simulated flight length incl. take-off [s] (default %(default)s)")
    p.add_argument("--jobs", type=int, default=e.jobs, help="flights in parallel (default: the CPU count, %(default)s)")
    p.add_argument("--modes", type=_csv, default=d.modes, help=f"comma list of {','.join(MODES)} (default: all)")
    p.add_argument("--trajectories", type=_csv, default=d.trajectories,
                   help=f"comma list of {','.join(TRAJECTORIES)} (default: all)")
    p.add_argument("--configs", type=_csv, default=d.configs,
                   help=f"comma list of configurations (default {','.join(CONFIGS)}; also robust, "
                        "robust+nn, outlier+nn+states, ...: harness/config.py PRESETS)")
    p.add_argument("--recorded", action=argparse.BooleanOptionalAction, default=None,
                   help="also replay the held-out recorded flights of the shared data; missing data is an error "
                        f"(default: yes, unless ${NO_RECORDED_ENV}=1)")
    p.add_argument("--data-dir", default=None, help="recorded data (default ../shared/data or $UWB_HIL_DATA)")
    p.add_argument("--firmware", default=str(DEFAULT_FIRMWARE), help="host firmware binary")
    p.add_argument("--sim-model", default=None,
                   help="bias model (.npz) for the simulated flights (default: the firmware's compiled-in model)")
    p.add_argument("--recorded-models", action=argparse.BooleanOptionalAction, default=d.recorded_models,
                   help="recorded flights on a firmware carrying the real-data networks of firmware_sim/models")
    p.add_argument("--pacing", choices=PACING_MODES, default=d.pacing,
                   help="pacing of the accuracy runs (windowed: same estimates as lockstep, much faster)")
    p.add_argument("--latency-runs", action=argparse.BooleanOptionalAction, default=d.latency_runs,
                   help="per mode, one extra real-time run for end-to-end latency")
    p.add_argument("--radio", type=_csv, default=(), metavar="tdoa2,tdoa3",
                   help="also fly the TDoA flights (simulated, and held-out UTIL recordings of that protocol) at LPS "
                        "radio level: their own rows, both levels of each flight, beside the measurement-level ones")
    p.add_argument("--timeout", type=float, default=e.timeout_s,
                   help="device silence before a run fails [s] (default %(default)s)")
    p.add_argument("--report", action=argparse.BooleanOptionalAction, default=True,
                   help="write the report when the runs are done (a shard: its own partial report)")
    p.add_argument("--shard", metavar="K/N", default=None,
                   help="run only shard K of N (1 <= K <= N; the flights dealt by estimated run time), e.g. "
                        "one per CI matrix job or Slurm array task; merge with `uwb-hil report DIR... --out M`")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="override an estimator setting in every run, e.g. --set proc_acc_xy=0.05 (repeatable; as "
                        "`uwb-hil run --set`); part of each run's fingerprint")
    p.add_argument("--keep-jsonl", action="store_true",
                   help="keep each run's per-measurement JSON Lines (gzip) besides its binary rows (.npy)")
    p.add_argument("--judge", type=_csv, default=None, metavar="CONFIGS",
                   help=f"configurations whose runs the verdict judges (default: every one flown except "
                        f"'{BASELINE_CONFIG}', the no-rejection baseline, which exists to be compared against and "
                        "legitimately diverges on real NLOS/TDoA3 data)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                   help="run every flight as a task on this Dask scheduler (default $UWB_HIL_SCHEDULER; none: the "
                        "local process pool). Workers need only the package ([cluster] extra); results come back here")
    _add_board_options(p)
    add_verdict_options(p)
    p.set_defaults(func=cmd_campaign)


def _add_board_options(p: argparse.ArgumentParser) -> None:
    boards = p.add_argument_group("boards", "run the flights on boards instead of one host build per flight: each "
                                  "board serves one flight at a time, the boards in parallel; a board that stops "
                                  "answering is taken out and its runs move to the others; every board is asked once more after the "
                                  "last flight (a lost board: exit 3)")
    boards.add_argument("--target", action="append", choices=TARGET_CHOICES, default=[],
                        help="a board of this kind (repeat: --target qemu --target qemu = two QEMU boards; host = "
                             "the host build on a pty); with --port: the kind of the ports' boards (default serial)")
    boards.add_argument("--port", action="append", default=[],
                        help="a board's serial port or pyserial URL (repeat for several boards)")
    boards.add_argument("--boards", metavar="FILE", default=None,
                        help="board list (YAML: name, port or serial_number, target, baud, firmware per board)")
    boards.add_argument("--baud", type=baud, default=DEFAULT_BAUD,
                        help="baud rate of --port boards (default %(default)s)")
    add_labgrid_options(boards)


def _executor(args: argparse.Namespace) -> AbstractContextManager[GroupExecutor | None]:
    """Where the flights run: boards (--target/--port/--boards), a Dask cluster (--scheduler /
    $UWB_HIL_SCHEDULER), else the local process pool."""
    boards = boards_from_options(list(args.target), list(args.port), args.baud)
    if args.boards:
        boards = check_unique(boards + load_board_list(Path(args.boards)))
    scheduler = scheduler_from(args.scheduler)
    if boards:
        if args.scheduler:
            raise UsageError("--scheduler runs flights on cluster workers' host builds: not with boards")
        return BoardExecutor(boards, log_dir=Path(args.out).resolve() / "logs")
    if scheduler is None:
        return nullcontext(None)
    from harness.campaign.cluster import ClusterOptions, DaskExecutor
    return DaskExecutor(ClusterOptions(scheduler=scheduler))


def cmd_campaign(args: argparse.Namespace) -> int:
    opts = CampaignOptions(seeds=args.seeds, first_seed=args.first_seed, duration_s=args.duration,
                           modes=tuple(args.modes), trajectories=tuple(args.trajectories), configs=tuple(args.configs),
                           recorded=_recorded(args),
                           data_dir=Path(args.data_dir) if args.data_dir else shared_data_dir(),
                           firmware=Path(args.firmware).resolve(), pacing=args.pacing,
                           latency_runs=args.latency_runs,
                           sim_model=Path(args.sim_model).resolve() if args.sim_model else None,
                           recorded_models=args.recorded_models, radio=tuple(args.radio), settings=tuple(args.set))
    ex = ExecOptions(jobs=args.jobs, timeout_s=args.timeout, keep_jsonl=args.keep_jsonl)
    criteria = criteria_from(args)          # refused (exit 2) before any run starts
    output_path(args.out, "--out", directory=True)
    judged = check_judged(args.judge, opts.configs) if args.judge is not None else default_judged(opts.configs)
    if not judged:          # the verdict would PASS on no run at all
        raise UsageError(f"the verdict judges no configuration of --configs {','.join(opts.configs)} (the baseline "
                         "none is not judged by default): add one, e.g. --configs none,outlier, or --judge none")
    shard = parse_shard(args.shard) if args.shard else None
    try:
        with _executor(args) as executor:
            outcome = plan_and_run(Path(args.out), opts, ex, shard=shard, executor=executor,
                                   log=lambda s: print(s, file=sys.stderr, flush=True))
    except RuntimeError as exc:     # a firmware image for a model could not be built
        print(f"uwb-hil: error: {exc}", file=sys.stderr)
        return 2
    return _conclude(args, outcome, criteria, judged)


def _board_out_text(b: dict[str, Any]) -> str:
    if b.get("after_last_flight"):
        return f"board {b['board']} taken out after its last flight ({b['reason']}), its runs stand"
    return f"board {b['board']} taken out ({b['reason']}), {b['moved_runs']} runs moved to the others"


def _conclude(args: argparse.Namespace, outcome: CampaignOutcome, criteria: Any, judged: tuple[str, ...]) -> int:
    """Judge, report and say what happened: 1 when a run failed or the verdict did, else 3 when a board was
    taken out (mid-campaign: the campaign completed on the others; found dead by the check after the last
    flight: its runs stand), else 0."""
    retried = f", {outcome.retries} retried" if outcome.retries else ""
    print(f"campaign: {outcome.total} runs: {outcome.skipped} resumed, {outcome.ok} ran ok, "
          f"{len(outcome.failed)} failed{retried}", file=sys.stderr)
    cdir = CampaignDir(Path(args.out).resolve())
    verdict = judge_campaign(cdir, outcome.runs, criteria, judged)
    if outcome.boards_out:
        note_boards_in_verdict(cdir, outcome.boards_out)
    if args.report:
        from harness.report.cli import write_report
        write_report(Path(args.out), as_json=False)
    out_text = "".join(f"; {_board_out_text(b)}" for b in outcome.boards_out)
    print(f"verdict: {'PASS' if verdict.passed else 'FAIL'} ({len(verdict.runs)} runs of "
          f"{', '.join(judged) or 'no configuration'} judged, {verdict.not_judged} not judged){out_text}")
    code = EXIT_DEVICE if outcome.boards_out else EXIT_PASS
    if outcome.boards_out:
        print(f"uwb-hil: {len(outcome.boards_out)} board(s) stopped answering during the campaign: "
              + ", ".join(b["board"] for b in outcome.boards_out), file=sys.stderr)
    if not outcome.all_ok:
        print(f"uwb-hil: campaign failed: {len(outcome.failed)} runs did not complete: "
              + ", ".join(f["run_id"] for f in outcome.failed), file=sys.stderr)
        code = EXIT_VERDICT
    if not verdict.passed:
        print(f"uwb-hil: verdict failed: {verdict.reason()}", file=sys.stderr)
        code = EXIT_VERDICT
    return code
