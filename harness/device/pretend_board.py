"""A pretend board: ONE host-firmware process serving a pty for as long as a test session (or any command)
runs, reached as a real board is, through its device path (`--uwb-port /dev/pts/N`, target serial).

A board on the bench is not restarted between tests: its counters keep counting and its TDoA engine keeps
its anchors. `uwb-fw --stdio` runs with the pty's master as stdin/stdout; the slave's path is the port.
The slave stays open here until the end (a pty whose slave every client closed gives the firmware EIO, and
it would exit between tests).

    python -m harness.device.pretend_board [--firmware PATH] -- pytest --uwb-port {port} tests/device

starts the board, runs the command with ``{port}`` replaced by the slave's path,
stops the board and exits with the command's code (3 when the board died during the command). The port is
not put in $UWB_HIL_PORT: the tests that run the CLI in a subprocess keep their own host device.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from harness.device.board_process import PtyBoard
from harness.errors import DeviceError
from harness.paths import DEFAULT_FIRMWARE

STARTUP_CHECK_S = 0.2


@contextmanager
def pretend_board(firmware: Path = DEFAULT_FIRMWARE, log: Path | None = None) -> Iterator[PtyBoard]:
    """One firmware process on a raw pty for the whole block (device/board_process.py's PtyBoard, the board a
    campaign starts too); always stopped at the end. `.port` is the path clients open, `.alive()`, `.pid`."""
    with PtyBoard(firmware, log) as board:
        time.sleep(STARTUP_CHECK_S)
        if not board.alive():
            raise DeviceError("the pretend board exited at start (its log: "
                              f"{log if log is not None else 'not kept; pass --log FILE'})")
        yield board


def run_with_board(command: Sequence[str], firmware: Path, log: Path | None) -> int:
    """Run `command` ({port} -> the board's path) against one pretend board; its exit code, 3 if the board died."""
    with pretend_board(firmware, log) as board:
        argv = [a.replace("{port}", board.port) for a in command]
        print(f"pretend board: {firmware} on {board.port} (pid {board.pid})", file=sys.stderr, flush=True)
        code = subprocess.run(argv, check=False).returncode
        if not board.alive():
            print("pretend board: the firmware exited during the command", file=sys.stderr)
            return code or 3
        return code


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.device.pretend_board", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--firmware", type=Path, default=DEFAULT_FIRMWARE, help="host firmware binary (%(default)s)")
    ap.add_argument("--log", type=Path, default=None, help="the firmware's stderr (default: discarded)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND ... ({port}: the board's path)")
    args = ap.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        ap.error("give a command after --, e.g. -- pytest --uwb-port {port} tests/device")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        return run_with_board(command, args.firmware, args.log)
    except (FileNotFoundError, DeviceError) as exc:
        print(f"pretend board: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, FileNotFoundError) else 3


if __name__ == "__main__":
    sys.exit(main())
