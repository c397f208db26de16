"""Boards the harness starts itself and that then stand as a real board would: up for the whole session,
reached through a serial port that clients open and close (a campaign's workers, a labgrid exporter).

  host   the host firmware with `--stdio` on a pty's master; the port is the pty's slave path
  qemu   the STM32 ELF in QEMU with its USART on a pty; the port is that pty
  serial a real board: nothing to start, the port is the board's

The slave of each pty stays open here for the board's life: a pty whose slave every client has closed gives
the firmware EIO (the host build would exit between clients). Nothing here reads it, so a client gets
every byte. `start_board` returns None for a real board.
"""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path
from types import TracebackType
from typing import IO, Protocol

from harness.device.board_list import BoardSpec
from harness.device.registry import default_firmware
from harness.errors import DeviceError
from harness.link.pty_link import make_raw


class BoardProcess(Protocol):
    port: str

    @property
    def pid(self) -> int | None: ...

    def alive(self) -> bool: ...

    def stop(self) -> None: ...


class PtyBoard:
    """The host firmware serving a pty (`uwb-fw --stdio` on the master); `port` is the slave path. The one
    implementation of a host board: a campaign's boards and device/pretend_board.py (pytest sessions) use it."""

    def __init__(self, firmware: Path, log_path: Path | None = None) -> None:
        self.firmware = Path(firmware)
        self.log_path = log_path
        self.port = ""
        self._proc: subprocess.Popen[bytes] | None = None
        self._slave: int | None = None
        self._log: IO[bytes] | None = None

    def start(self) -> PtyBoard:
        if not self.firmware.is_file():
            raise FileNotFoundError(f"firmware binary {self.firmware} not found: run `make firmware`")
        master, slave = os.openpty()
        make_raw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        try:
            self._proc = subprocess.Popen([str(self.firmware), "--stdio"], stdin=master, stdout=master,
                                          stderr=self._log if self._log else subprocess.DEVNULL,
                                          start_new_session=True)
        finally:
            os.close(master)
        return self

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def stop(self) -> None:
        proc, self._proc = self._proc, None
        if proc is not None:
            stop_process(proc)
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self) -> PtyBoard:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.stop()


class QemuBoard:
    """The STM32 ELF in QEMU, its USART on a pty that clients open as `port`."""

    def __init__(self, elf: Path, log_path: Path) -> None:
        from harness.device.qemu_process import QemuOptions, QemuProcess
        self._qemu = QemuProcess(Path(elf), log_path, QemuOptions(serial="pty"))
        self.port = ""

    def start(self) -> QemuBoard:
        from harness.device.qemu_process import QemuError
        try:
            self._qemu.start()      # keeps its own fd on the pty open (never read again): the slave stays open
        except QemuError as exc:
            raise DeviceError(f"cannot start QEMU board: {exc}") from exc
        assert self._qemu.serial_name is not None
        self.port = self._qemu.serial_name
        return self

    @property
    def pid(self) -> int | None:
        proc = self._qemu.proc
        return proc.pid if proc is not None else None

    def alive(self) -> bool:
        return self._qemu.alive()

    def stop(self) -> None:
        self._qemu.stop()


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 5.0) -> None:
    """SIGTERM, then SIGKILL if the process has not ended within `timeout_s`; reaped either way. SIGCONT
    after the SIGTERM: a stopped (frozen) process acts on it at once instead of costing the whole timeout."""
    if proc.poll() is None:
        proc.terminate()
        proc.send_signal(signal.SIGCONT)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def start_board(board: BoardSpec, log_dir: Path) -> BoardProcess | None:
    """Start a board the harness runs itself (host build, QEMU); None for a real board (serial)."""
    firmware = Path(board.firmware) if board.firmware is not None else default_firmware(board.target)
    if board.target in ("host", "asan"):
        return PtyBoard(firmware, log_dir / f"board-{board.name}.log").start()
    if board.target == "qemu":
        return QemuBoard(firmware, log_dir / f"board-{board.name}.qemu.log").start()
    return None
