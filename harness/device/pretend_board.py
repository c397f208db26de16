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
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from harness.errors import DeviceError
from harness.link.pty_link import make_raw
from harness.paths import DEFAULT_FIRMWARE

STARTUP_CHECK_S = 0.2
STOP_TIMEOUT_S = 5.0


class PretendBoard:
    """The firmware process and the port it serves (the pty slave's path)."""

    def __init__(self, proc: subprocess.Popen[bytes], port: str, log: Path | None) -> None:
        self.proc, self.port, self.log = proc, port, log

    def alive(self) -> bool:
        return self.proc.poll() is None


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextmanager
def pretend_board(firmware: Path = DEFAULT_FIRMWARE, log: Path | None = None) -> Iterator[PretendBoard]:
    """One firmware process on a raw pty for the whole block; always stopped at the end."""
    if not Path(firmware).is_file():
        raise FileNotFoundError(f"firmware binary {firmware} not found: run `make firmware`")
    master, slave = os.openpty()
    make_raw(slave)
    out: IO[bytes] | int = open(log, "wb") if log is not None else subprocess.DEVNULL
    try:
        proc = subprocess.Popen([str(firmware), "--stdio"], stdin=master, stdout=master, stderr=out,
                                start_new_session=True)
    finally:
        os.close(master)
        if not isinstance(out, int):
            out.close()
    try:
        time.sleep(STARTUP_CHECK_S)
        if proc.poll() is not None:
            raise DeviceError(f"the pretend board exited at start (code {proc.returncode})")
        yield PretendBoard(proc, os.ttyname(slave), log)
    finally:
        _stop(proc)
        os.close(slave)


def run_with_board(command: Sequence[str], firmware: Path, log: Path | None) -> int:
    """Run `command` ({port} -> the board's path) against one pretend board; its exit code, 3 if the board died."""
    with pretend_board(firmware, log) as board:
        argv = [a.replace("{port}", board.port) for a in command]
        print(f"pretend board: {firmware} on {board.port} (pid {board.proc.pid})", file=sys.stderr, flush=True)
        code = subprocess.run(argv, check=False).returncode
        if not board.alive():
            print(f"pretend board: the firmware exited during the command (code {board.proc.returncode})",
                  file=sys.stderr)
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
