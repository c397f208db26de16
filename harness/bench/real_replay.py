"""`make bench` (real-flight replay): one shared Crazyflie uSD flight (IMU ~1 kHz + TDoA) replayed through
the host build and through the STM32F405 build under QEMU over each of its links, the same command line for
all (`uwb-hil run --recording LOG --stages outlier --json`, windowed pacing):
  host              the host build on a pty
  qemu usart        uwb-fw.elf, frames through the emulated USART: what a serial line gives (QEMU moves one
                    byte per main-loop iteration, docs/qemu.md: the link sets the pace)
  qemu semihosting  uwb-fw-semihost.elf, frames in whole blocks by ARM semihosting (`--qemu-link
                    semihosting`): the guest's arithmetic sets the pace

    python -m harness.bench.real_replay [--recording LOG] [--json] [--no-usart]

Figures: flight seconds over wall seconds (x real time) per target, the link traffic the replay needs per
flight second (the bytes `uwb-hil run` writes: every IMU sample and UWB measurement as a frame) and the bytes
per wall second each link reached. For the semihosting replay also the guest's executed instructions (QEMU
-icount: the count the guest prints at the end, in QEMU's log) per flight second, and the emulator's speed on
this firmware: guest instructions per second of QEMU's own CPU time (independent of what else loads the
machine), hence the x real time QEMU alone could reach. The replays' flight RMSE must agree (same core).
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
TARGETS = (("host", ("--target", "host")), ("qemu usart", ("--target", "qemu", "--qemu-link", "usart")),
           ("qemu semihosting", ("--target", "qemu", "--qemu-link", "semihosting")))
TICKS_RE = re.compile(r"uwb-fw-semihost: link closed after (\d+) ticks")
CPU_RE = re.compile(r"harness: QEMU CPU time ([0-9.]+) s")


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
    qemu_cpu_s: float | None = None           # semihosting: QEMU's CPU time (user + system) for the replay

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


def replay(recording: Path, target: str, device_args: tuple[str, ...], n_bytes: int, timeout_s: float) -> ReplayFigure:
    with tempfile.TemporaryDirectory(prefix="uwb-real-replay-") as logs:
        # --no-tof: the paper's system, the frames link_bytes counts
        code, out, reason = run_json((str(recording), "--stages", "outlier", "--no-tof", *device_args, "--log-dir",
                                      logs), timeout_s)
        log = "".join(p.read_text(errors="replace") for p in sorted(Path(logs).glob("qemu-*.log")))
    if out is None or "wall_s" not in out:
        raise RuntimeError(f"{target} replay of {recording.name} failed (exit {code}): {reason}")
    wall = float(out["wall_s"])
    ticks, cpu = TICKS_RE.search(log), CPU_RE.search(log)
    return ReplayFigure(target, float(out["sim_s"]), wall, float(out["realtime_factor"]), n_bytes,
                        n_bytes / wall if wall > 0 else float("nan"),
                        float(out["accuracy"]["phases"]["flight"]["rmse"]),
                        int(ticks.group(1)) if ticks else None, float(cpu.group(1)) if cpu else None)


def print_table(recording: Path, figs: list[ReplayFigure], n_bytes: int) -> None:
    print(f"== real-flight replay: {recording.name} ({figs[0].flight_s:.1f} s of flight, {n_bytes / 1e6:.2f} MB "
          f"of frames, {n_bytes / figs[0].flight_s / 1e3:.0f} kB per flight second), IMU + outlier, windowed")
    print(f"{'target':17} {'wall s':>8} {'x real time':>11} {'link kB/s':>10} {'flight RMSE m':>14}")
    for f in figs:
        print(f"{f.target:17} {f.wall_s:8.2f} {f.realtime_factor:10.2f}x {f.link_bytes_per_wall_s / 1e3:10.1f} "
              f"{f.flight_rmse_m:14.3f}")
    for f in figs:
        if f.guest_instructions and f.qemu_cpu_s:
            per_s = f.guest_instructions / f.flight_s
            print(f"{f.target}: {f.guest_instructions / 1e6:.1f} M guest instructions ({per_s / 1e6:.2f} M per flight "
                  f"second) in {f.qemu_cpu_s:.2f} s of QEMU CPU: {f.guest_mips_per_cpu_s:.0f} M instructions per "
                  f"CPU second, {f.guest_instructions / f.wall_s / 1e6:.0f} M per wall second; QEMU alone: "
                  f"{f.cpu_bound_realtime_factor:.0f}x real time (100x needs {100 * per_s / 1e6:.0f} M/s)")
    host = figs[0]
    for f in figs[1:]:
        print(f"{f.target} / host speed: {f.realtime_factor / host.realtime_factor:.4f}x; >= 100x real time: "
              f"{'met' if f.realtime_factor >= 100 else 'NOT met'}")
    print(f"host >= 100x real time: {'met' if host.realtime_factor >= 100 else 'NOT met'}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.bench.real_replay", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recording", type=Path, help=f"a Crazyflie uSD log (default: <data>/{DEFAULT_FLIGHT})")
    ap.add_argument("--timeout", type=float, default=900.0, help="per replay [s]")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-usart", action="store_true", help="skip the QEMU USART replay (~80 s here)")
    args = ap.parse_args(argv)
    recording = args.recording or shared_data_dir() / DEFAULT_FLIGHT
    if not recording.exists():
        print(f"harness.bench.real_replay: skipped: {recording} not found (the shared data, UWB_HIL_DATA)",
              file=sys.stderr)
        return 0 if args.recording is None else 2
    n_bytes = link_bytes(recording)
    try:
        figs = [replay(recording, t, dev, n_bytes, args.timeout) for t, dev in TARGETS
                if not (args.no_usart and t == "qemu usart")]
    except (RuntimeError, OSError) as e:
        print(f"harness.bench.real_replay: error: {e}", file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps([{**asdict(f), "guest_mips_per_cpu_s": f.guest_mips_per_cpu_s,
                           "cpu_bound_realtime_factor": f.cpu_bound_realtime_factor} for f in figs], indent=2))
        return 0
    print_table(recording, figs, n_bytes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
