"""`make bench` (real-flight replay): one shared Crazyflie uSD flight (IMU ~1 kHz + TDoA) replayed through
the host build and through the STM32F405 build under QEMU over each of its links, the same command line for
all (`uwb-hil run --recording LOG --stages outlier --no-tof --json`, windowed pacing):
  host              the host build on a pty
  qemu usart        uwb-fw.elf, frames through the emulated USART: what a serial line gives (QEMU moves one
                    byte per main-loop iteration, docs/qemu.md: the link sets the pace)
  qemu semihosting  uwb-fw-semihost.elf, frames in whole blocks by ARM semihosting (`--qemu-link
                    semihosting`): the guest's arithmetic sets the pace. Timed with `--qemu-clock host` (no
                    -icount: QEMU's fastest mode); the guest's instruction count comes from one more replay
                    with -icount (the default clock), whose speed is printed too.

    python -m harness.bench.real_replay [--recording LOG] [--json] [--no-usart] [--runs N]

Each timed replay runs N times (default 3; the machine may be shared): the table gives the median and the
range. Figures: flight seconds over wall seconds (x real time) per target, the link traffic the replay needs
per flight second (the bytes `uwb-hil run` writes: every IMU sample and UWB measurement as a frame) and the bytes
per wall second each link reached. For the semihosting replays also QEMU's own CPU time (user + system, from
/proc, written to its log once started and at the end of input: the difference, its start-up left out), the guest's executed instructions (the -icount replay: the
count the guest prints at the end, in QEMU's log) per flight second, and the emulator's speed on this firmware:
guest instructions per second of QEMU's CPU time (independent of what else loads the machine), hence the x
real time QEMU alone could reach. The replays' flight RMSE must agree (same core).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from harness.paths import shared_data_dir
from harness.report.replay_all import run_json

DEFAULT_FLIGHT = Path("cf_usd") / "0425" / "0425-traj3"
#: (label, `uwb-hil run` device options)
SEMIHOST = ("--target", "qemu", "--qemu-link", "semihosting")
TARGETS = (("host", ("--target", "host")), ("qemu usart", ("--target", "qemu", "--qemu-link", "usart")),
           ("qemu semihosting", (*SEMIHOST, "--qemu-clock", "host")))
#: the replay whose guest prints its executed instructions (TIM2 under -icount shift=0)
COUNT_TARGET = ("qemu semihosting -icount", SEMIHOST)
TICKS_RE = re.compile(r"uwb-fw-semihost: link closed after (\d+) ticks")
CPU_RE = re.compile(r"harness: QEMU CPU time ([0-9.]+) s at the end of input")
START_CPU_RE = re.compile(r"harness: QEMU CPU time ([0-9.]+) s at start")


@dataclass(frozen=True)
class ReplayFigure:
    target: str
    flight_s: float
    wall_s: float
    realtime_factor: float
    link_bytes: int
    link_bytes_per_wall_s: float
    flight_rmse_m: float
    guest_instructions: int | None = None     # semihosting: executed by the guest (-icount), from QEMU's log
    qemu_cpu_s: float | None = None           # semihosting: QEMU's CPU time (user + system) for the replay (from
                                              # its start-up's end to the end of input)

    @property
    def guest_mips_per_cpu_s(self) -> float | None:
        """Millions of guest instructions per second of QEMU's CPU: the emulator's speed on this firmware."""
        return self.guest_instructions / self.qemu_cpu_s / 1e6 if self.guest_instructions and self.qemu_cpu_s else None

    @property
    def cpu_bound_realtime_factor(self) -> float | None:
        """x real time if the replay took only QEMU's CPU time (no harness, no other load)."""
        return self.flight_s / self.qemu_cpu_s if self.qemu_cpu_s else None


def link_bytes(recording: Path) -> int:
    """The bytes the host writes for this recording (PreparedFlight.stream, as the streamer sends it)."""
    from harness.flight.loaders import load_recording
    from harness.stream.prepare import prepare
    return len(prepare(load_recording(recording), seq0=0).stream)


def replay(recording: Path, target: str, device_args: tuple[str, ...], n_bytes: int, timeout_s: float,
           count: bool = False) -> ReplayFigure:
    """One replay; `count`: the guest ran under -icount and its tick count is its executed instructions."""
    with tempfile.TemporaryDirectory(prefix="uwb-real-replay-") as logs:
        # --no-tof: the paper's system, the frames link_bytes counts
        code, out, reason = run_json((str(recording), "--stages", "outlier", "--no-tof", *device_args, "--log-dir",
                                      logs), timeout_s)
        log = "".join(p.read_text(errors="replace") for p in sorted(Path(logs).glob("qemu-*.log")))
    if out is None or "wall_s" not in out:
        raise RuntimeError(f"{target} replay of {recording.name} failed (exit {code}): {reason}")
    wall = float(out["wall_s"])
    ticks, cpu, start = TICKS_RE.search(log), CPU_RE.search(log), START_CPU_RE.search(log)
    cpu_s = float(cpu.group(1)) - (float(start.group(1)) if start else 0.0) if cpu else None
    return ReplayFigure(target, float(out["sim_s"]), wall, float(out["realtime_factor"]), n_bytes,
                        n_bytes / wall if wall > 0 else float("nan"),
                        float(out["accuracy"]["phases"]["flight"]["rmse"]),
                        int(ticks.group(1)) if (ticks and count) else None, cpu_s)


def median_run(runs: list[ReplayFigure]) -> ReplayFigure:
    """The run of median speed (the upper one of an even count)."""
    return sorted(runs, key=lambda f: f.realtime_factor)[len(runs) // 2]


def _range(values: list[float], fmt: str) -> str:
    return f"{min(values):{fmt}}-{max(values):{fmt}}" if len(values) > 1 else ""


def print_table(recording: Path, runs: dict[str, list[ReplayFigure]], n_bytes: int) -> None:
    first = next(iter(runs.values()))[0]
    n_runs = max(len(r) for r in runs.values())
    print(f"== real-flight replay: {recording.name} ({first.flight_s:.1f} s of flight, {n_bytes / 1e6:.2f} MB "
          f"of frames, {n_bytes / first.flight_s / 1e3:.0f} kB per flight second), IMU + outlier, windowed; "
          f"median of {n_runs} runs (range)")
    print(f"{'target':25} {'wall s':>8} {'x real time':>11} {'(range)':>13} {'QEMU CPU s':>10} {'link kB/s':>10} "
          f"{'flight RMSE m':>14}")
    for target, figs in runs.items():
        f = median_run(figs)
        cpu = f"{f.qemu_cpu_s:10.2f}" if f.qemu_cpu_s else f"{'':10}"
        print(f"{target:25} {f.wall_s:8.2f} {f.realtime_factor:10.1f}x "
              f"{_range([g.realtime_factor for g in figs], '.0f'):>13} {cpu} {f.link_bytes_per_wall_s / 1e3:10.1f} "
              f"{f.flight_rmse_m:14.3f}")
    count = next((g for g in runs.get(COUNT_TARGET[0], []) if g.guest_instructions), None)
    if count is not None and count.guest_instructions:
        per_s = count.guest_instructions / count.flight_s
        print(f"guest: {count.guest_instructions / 1e6:.1f} M instructions ({per_s / 1e6:.2f} M per flight second; "
              f"100x real time needs {100 * per_s / 1e6:.0f} M/s)")
        for target in ("qemu semihosting", COUNT_TARGET[0]):
            cpus = [g.qemu_cpu_s for g in runs.get(target, []) if g.qemu_cpu_s]
            if cpus:
                cpu = sorted(cpus)[len(cpus) // 2]
                print(f"{target}: {count.guest_instructions / cpu / 1e6:.0f} M instructions per second of QEMU CPU "
                      f"(median {cpu:.2f} s); QEMU alone: {count.flight_s / cpu:.0f}x real time")
    host = median_run(runs["host"]) if "host" in runs else None
    for target, figs in runs.items():
        f = median_run(figs)
        ratio = f" ({f.realtime_factor / host.realtime_factor:.3f} of the host's)" if host and f is not host else ""
        print(f"{target} >= 100x real time: {'met' if f.realtime_factor >= 100 else 'NOT met'}{ratio}")


def run_all(recording: Path, args: argparse.Namespace, n_bytes: int) -> dict[str, list[ReplayFigure]]:
    runs: dict[str, list[ReplayFigure]] = {}
    for target, dev in (*TARGETS, COUNT_TARGET):
        if args.no_usart and target == "qemu usart":
            continue
        n = 1 if target == "qemu usart" else args.runs     # the USART replay takes minutes
        runs[target] = [replay(recording, target, dev, n_bytes, args.timeout, count=target == COUNT_TARGET[0])
                        for _ in range(n)]
    return runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.bench.real_replay", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", type=Path, help=f"a Crazyflie uSD log (default: <data>/{DEFAULT_FLIGHT})")
    ap.add_argument("--timeout", type=float, default=900.0, help="per replay [s]")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-usart", action="store_true", help="skip the QEMU USART replay (~80 s here)")
    ap.add_argument("--runs", type=int, default=3, help="timed replays per target (median and range; default 3)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        print("harness.bench.real_replay: error: --runs must be >= 1", file=sys.stderr)
        return 2
    recording = args.recording or shared_data_dir() / DEFAULT_FLIGHT
    if not recording.exists():
        print(f"harness.bench.real_replay: skipped: {recording} not found (the shared data, UWB_HIL_DATA)",
              file=sys.stderr)
        return 0 if args.recording is None else 2
    n_bytes = link_bytes(recording)
    try:
        runs = run_all(recording, args, n_bytes)
    except (RuntimeError, OSError) as e:
        print(f"harness.bench.real_replay: error: {e}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps({t: [{**asdict(f), "guest_mips_per_cpu_s": f.guest_mips_per_cpu_s,
                               "cpu_bound_realtime_factor": f.cpu_bound_realtime_factor} for f in figs]
                          for t, figs in runs.items()}, indent=2))
        return 0
    print_table(recording, runs, n_bytes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
