"""The flash hook: a user command that puts the firmware on the board before a test session
(`pytest --uwb-flash-cmd "st-flash write build/uwb-fw.bin 0x8000000"`, or `uwb_flash_cmd` in the ini file).

The command runs through the shell (it is the user's own command line, as in a Makefile), with a time
limit; its output goes to the log (logger "uwb_hil.flash" and a file), and a failure names the command,
its exit status and the tail of its output.
"""

from __future__ import annotations

import logging
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from harness.errors import DeviceError

LOG = logging.getLogger("uwb_hil.flash")


class FlashError(DeviceError):
    """The flash command failed or timed out."""


@dataclass(frozen=True)
class FlashResult:
    command: str
    returncode: int
    seconds: float
    output: str
    log_path: Path | None


def run_flash_command(command: str, timeout_s: float, log_path: Path | None = None) -> FlashResult:
    LOG.info("flash: running %s (time limit %.0f s)", command, timeout_s)
    t0 = time.monotonic()
    try:
        proc = subprocess.run(command, shell=True, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, timeout=timeout_s, check=False)
        output, code = proc.stdout.decode(errors="replace"), proc.returncode
    except subprocess.TimeoutExpired as exc:
        output = (exc.output or b"").decode(errors="replace")
        _write_log(log_path, command, output, None)
        raise FlashError(f"flash command {command!r} did not finish within {timeout_s:g} s; "
                         f"last output: {_tail(output)}") from None
    seconds = time.monotonic() - t0
    for line in output.splitlines():
        LOG.info("flash: %s", line)
    _write_log(log_path, command, output, code)
    if code != 0:
        raise FlashError(f"flash command {command!r} failed (exit {code}); last output: {_tail(output)}")
    LOG.info("flash: done in %.1f s", seconds)
    return FlashResult(command=command, returncode=code, seconds=seconds, output=output, log_path=log_path)


def _write_log(path: Path | None, command: str, output: str, code: int | None) -> None:
    if path is not None:
        path.write_text(f"$ {command}\n{output}\n[exit {code if code is not None else 'timeout'}]\n",
                        encoding="utf-8")


def _tail(text: str, lines: int = 3) -> str:
    """The last lines on one line (error messages are one line; the whole output is in the log)."""
    return " | ".join(ln.strip() for ln in text.splitlines()[-lines:] if ln.strip()) or "(none)"
