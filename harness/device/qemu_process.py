"""QemuProcess: qemu-system-arm with the STM32F405 firmware ELF, its HMP monitor and the host end of the guest's
link: the USART (a unix socket, or the pty of the older recipe), or, for the emulator build uwb-fw-semihost.elf,
two FIFOs the guest reads and writes in whole blocks through ARM semihosting (link="semihosting", docs/qemu.md).
The device on top of it is harness/device/qemu.py."""

from __future__ import annotations

import os
import re
import select
import shutil
import socket
import subprocess
import tempfile
import time
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from harness.errors import DeviceError
from harness.link.pty_link import make_raw

_PTY_RE = re.compile(r"char device redirected to (/dev/pts/\d+) \(label (\w+)\)")
_PROMPT = b"(qemu) "
# `-serial` index -> USART base address on the STM32F405 SoC model (hw/arm/stm32f405_soc.c).
USART_BASES = (0x40011000, 0x40004400, 0x40004800, 0x40004C00, 0x40005000, 0x40011400, 0x40007800)
_USART_CR1 = 0x0C
_CR1_UE_RE = (1 << 13) | (1 << 2)
_ANSI_RE = re.compile(rb"\x1b\[[0-9;]*[A-Za-z]")
#: the guest's link: "usart" (the emulated USART, one byte per QEMU main-loop iteration) or "semihosting"
#: (SYS_READ/SYS_WRITE of whole blocks on two FIFOs; only the emulator build uwb-fw-semihost.elf speaks it)
LINKS = ("usart", "semihosting")
#: the FIFOs of the semihosting link, in QEMU's working directory (names fixed in stm32/semihost_link.c)
SEMIHOST_IN, SEMIHOST_OUT = "uwb-link.in", "uwb-link.out"


class QemuError(DeviceError):
    """QEMU could not be started, or stopped answering its monitor."""


@dataclass(frozen=True)
class QemuOptions:
    machine: str = "netduinoplus2"
    icount: bool = True              # -icount shift=0: 1 ns virtual time per instruction (deterministic)
    serial_index: int = 0            # 0 = USART1 (the firmware's default link), 2 = USART3
    start_timeout_s: float = 10.0    # QEMU must be up (socket / pty name) within this
    serial: str = "socket"           # host end of the USART: "socket" (unix socket) or "pty"
    link: str = "usart"              # the guest's link (LINKS); "semihosting" needs uwb-fw-semihost.elf
    settle_s: float = 1.2            # pty only: > QEMU's 1 s pty poll, time for it to see the opened slave
    stop_timeout_s: float = 3.0
    qemu: str = "qemu-system-arm"

    def command(self, elf: Path, monitor_path: Path, serial_path: Path | None = None) -> list[str]:
        cmd = [self.qemu, "-M", self.machine, "-display", "none", "-nodefaults",
               "-monitor", f"unix:{monitor_path},server=on,wait=off"]
        if self.link not in LINKS:
            raise QemuError(f"unknown QEMU link {self.link!r}: {' or '.join(LINKS)}")
        if self.link == "semihosting":
            return [*cmd, "-semihosting-config", "enable=on,target=native", "-kernel", str(elf.resolve()), "-S",
                    *self._icount()]
        if self.serial == "socket":
            if serial_path is None:
                raise QemuError("serial='socket' needs the socket path")
            cmd += ["-chardev", f"socket,id=uwblink,path={serial_path},server=on,wait=off"]
            link = "chardev:uwblink"
        elif self.serial == "pty":
            link = "pty"
        else:
            raise QemuError(f"unknown serial transport {self.serial!r}: 'socket' or 'pty'")
        # serial0..serialN: only the link's USART is connected, the ones before it are null.
        cmd += ["-serial", "null"] * self.serial_index + ["-serial", link]
        return [*cmd, "-kernel", str(elf.resolve()), "-S", *self._icount()]

    def _icount(self) -> list[str]:
        return ["-icount", "shift=0,align=off"] if self.icount else []


class QemuProcess:
    """One QEMU instance with the guest's link USART on a raw pty and an HMP monitor socket."""

    def __init__(self, elf: Path, log_path: Path, options: QemuOptions = QemuOptions()) -> None:
        self.elf = Path(elf)
        self.log_path = Path(log_path)
        self.options = options
        self.proc: subprocess.Popen[bytes] | None = None
        self.serial_name: str | None = None    # the host end: "/dev/pts/N", "unix:<socket>" or "semihosting:<dir>"
        self.fd: int = -1                      # the host end's fd (read and write; semihosting: read only)
        self.write_fd: int = -1                # semihosting: the FIFO the guest reads (else fd)
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._mon: socket.socket | None = None
        self._log: IO[bytes] | None = None
        self._finalizer: weakref.finalize[..., QemuProcess] | None = None

    # ---------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        if not self.elf.is_file():
            raise QemuError(f"firmware {self.elf} not found: build it with `make stm32`")
        if shutil.which(self.options.qemu) is None:
            raise QemuError(f"{self.options.qemu} not found: run scripts/ensure_arm_tools.sh")
        self._tmp = tempfile.TemporaryDirectory(prefix="uwb-qemu-")
        mon_path = Path(self._tmp.name) / "monitor.sock"
        serial_path = Path(self._tmp.name) / "serial.sock"
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        cmd = self.options.command(self.elf, mon_path, serial_path)
        self._log.write(("$ " + " ".join(cmd) + "\n").encode())
        self._log.flush()
        try:
            if self.options.link == "semihosting":
                self._open_fifos(Path(self._tmp.name))
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self._log,
                                         stderr=subprocess.STDOUT, start_new_session=True, cwd=self._tmp.name)
            # QEMU runs in its own session: make sure it never outlives a harness that forgot stop().
            self._finalizer = weakref.finalize(self, _kill_quietly, self.proc)
            if self.options.link == "semihosting":
                self._mon = self._connect_monitor(mon_path)
                self.monitor("cont")    # the FIFOs hold what the host writes before the guest opens them
                self._log_cpu_time(self.proc.pid, "at start")
                return
            if self.options.serial == "socket":
                self.fd = self._connect_serial(serial_path)
                self.serial_name = f"unix:{serial_path}"
                self._mon = self._connect_monitor(mon_path)
                self._wait_for_serial_connected()
            else:
                self.serial_name = self._wait_for_pty()
                self.fd = _open_raw(self.serial_name)
                self._mon = self._connect_monitor(mon_path)
                # QEMU learns that the slave is open on its next 1 s poll; until then the guest's first
                # bytes would be dropped. The CPU is still halted (-S), so simply wait, then run.
                time.sleep(self.options.settle_s)
            self.monitor("cont")
            self._wait_for_receiver()
        except BaseException:
            self.stop()
            raise

    def _open_fifos(self, tmp: Path) -> None:
        """The semihosting link's FIFOs, opened before QEMU starts so that the guest's SYS_OPENs never wait:
        the one it writes read-only (a reader exists), the one it reads read-write (a writer exists, and
        closing it is the guest's end of input)."""
        os.mkfifo(tmp / SEMIHOST_IN)
        os.mkfifo(tmp / SEMIHOST_OUT)
        self.fd = os.open(tmp / SEMIHOST_OUT, os.O_RDONLY | os.O_NONBLOCK)
        self.write_fd = os.open(tmp / SEMIHOST_IN, os.O_RDWR | os.O_NONBLOCK)
        self.serial_name = f"semihosting:{tmp}"

    def _end_semihosting(self, proc: subprocess.Popen[bytes]) -> None:
        """Close the guest's input: it answers what is left, prints its instruction count and exits
        (SYS_EXIT). Its output is drained meanwhile (a full FIFO would block it), bounded by stop_timeout_s.
        While the guest waits in SYS_READ QEMU holds its big lock and its monitor does not answer, so
        "quit" would not work before this."""
        self._log_cpu_time(proc.pid, "at the end of input")
        os.close(self.write_fd)
        self.write_fd = -1
        deadline = time.monotonic() + self.options.stop_timeout_s
        while proc.poll() is None and time.monotonic() < deadline and self.fd >= 0:
            r, _, _ = select.select([self.fd], [], [], 0.05)
            try:
                if r and not os.read(self.fd, 65536):
                    break
            except OSError:
                break

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def _log_cpu_time(self, pid: int, when: str) -> None:
        """The CPU seconds QEMU has used so far (user + system, /proc/PID/stat), as one line of its log: with the
        guest's instruction count, which it prints at the end, the emulator's speed on this firmware, whatever
        else loads the machine (harness/bench/real_replay.py)."""
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            cpu_s = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return
        if self._log is not None:
            self._log.write(f"harness: QEMU CPU time {cpu_s:.3f} s {when}\n".encode())
            self._log.flush()

    def stop(self) -> None:
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        proc, self.proc = self.proc, None
        if proc is not None and self.write_fd >= 0:
            self._end_semihosting(proc)
        if proc is not None and proc.poll() is None:
            if self._mon is not None:
                try:
                    self._mon.sendall(b"quit\n")
                except OSError:
                    pass
            try:
                proc.wait(self.options.stop_timeout_s)
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(self.options.stop_timeout_s)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(self.options.stop_timeout_s)
        if self._mon is not None:
            self._mon.close()
            self._mon = None
        for fd in (self.fd, self.write_fd):
            if fd >= 0:
                os.close(fd)
        self.fd = self.write_fd = -1
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    # ---------------------------------------------------------------------------- monitor
    def monitor(self, command: str, timeout: float = 5.0) -> str:
        """Run one HMP command and return its output (echo, escapes and prompt removed)."""
        if self._mon is None:
            raise QemuError("monitor not connected")
        self._mon.sendall(command.encode() + b"\n")
        out = self._read_until_prompt(timeout)
        text = _ANSI_RE.sub(b"", out).replace(b"\r", b"").decode(errors="replace")
        _echo, _, body = text.partition("\n")  # the first line is the monitor's echo of the command
        return body.strip("\n")

    def read_words(self, addr: int, count: int, timeout: float = 10.0) -> list[int]:
        """Read `count` 32-bit words of guest physical memory (HMP `xp`)."""
        words: list[int] = []
        chunk = 256
        for base in range(addr, addr + 4 * count, 4 * chunk):
            n = min(chunk, (addr + 4 * count - base) // 4)
            out = self.monitor(f"xp /{n}xw {base:#x}", timeout)
            for line in out.splitlines():
                if ":" in line:
                    words += [int(w, 16) for w in line.split(":", 1)[1].split()]
        if len(words) != count:
            raise QemuError(f"xp returned {len(words)} words, expected {count}")
        return words

    def _read_until_prompt(self, timeout: float) -> bytes:
        assert self._mon is not None
        deadline = time.monotonic() + timeout
        buf = b""
        while not buf.endswith(_PROMPT):
            left = deadline - time.monotonic()
            if left <= 0:
                raise QemuError(f"QEMU monitor did not answer within {timeout:.1f} s (log: {self.log_path})")
            r, _, _ = select.select([self._mon], [], [], left)
            if r:
                data = self._mon.recv(65536)
                if not data:
                    raise QemuError(f"QEMU monitor closed (log: {self.log_path})")
                buf += data
        return buf[: -len(_PROMPT)]

    def _connect_monitor(self, path: Path) -> socket.socket:
        deadline = time.monotonic() + self.options.start_timeout_s
        while True:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                s.connect(str(path))
                self._mon = s
                self._read_until_prompt(max(0.1, deadline - time.monotonic()))  # banner
                return s
            except (FileNotFoundError, ConnectionRefusedError):
                s.close()
                if time.monotonic() > deadline or not self.alive():
                    raise QemuError(f"QEMU monitor socket {path} never came up (log: {self.log_path})") from None
                time.sleep(0.02)

    def _connect_serial(self, path: Path) -> int:
        """Connect to QEMU's listening serial socket; the raw fd (non-blocking), owned by this process."""
        deadline = time.monotonic() + self.options.start_timeout_s
        while True:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                s.connect(str(path))
            except (FileNotFoundError, ConnectionRefusedError):
                s.close()
                if time.monotonic() > deadline or not self.alive():
                    raise QemuError(f"QEMU serial socket {path} never came up (log: {self.log_path})") from None
                time.sleep(0.005)
                continue
            s.setblocking(False)
            return s.detach()

    def _wait_for_serial_connected(self) -> None:
        """Until QEMU has accepted our connection, the guest's bytes would go nowhere: `info chardev` shows
        the socket's filename with a "disconnected:" prefix until then."""
        deadline = time.monotonic() + self.options.start_timeout_s
        while True:
            lines = [ln for ln in self.monitor("info chardev").splitlines() if ln.startswith("uwblink:")]
            if lines and "disconnected:" not in lines[0]:
                return
            if time.monotonic() > deadline:
                raise QemuError(f"QEMU did not accept the serial connection within {self.options.start_timeout_s:.0f} s"
                                f" ({lines}; log: {self.log_path})")
            time.sleep(0.002)

    def _wait_for_receiver(self) -> None:
        """QEMU's USART model drops bytes that arrive before the guest set CR1.UE|RE, and the host
        may write the moment `cont` returns: wait until the firmware has enabled its receiver."""
        cr1 = USART_BASES[self.options.serial_index] + _USART_CR1
        deadline = time.monotonic() + self.options.start_timeout_s
        while True:
            if self.read_words(cr1, 1)[0] & _CR1_UE_RE == _CR1_UE_RE:
                return
            if time.monotonic() > deadline:
                raise QemuError(f"the firmware did not enable its USART within {self.options.start_timeout_s:.0f} s"
                                f" (log: {self.log_path})")
            time.sleep(0.005)

    def _wait_for_pty(self) -> str:
        deadline = time.monotonic() + self.options.start_timeout_s
        while time.monotonic() < deadline:
            text = self.log_path.read_text(errors="replace")
            m = _PTY_RE.search(text)
            if m:
                return m.group(1)
            if not self.alive():
                raise QemuError(f"QEMU exited during start-up:\n{text[-2000:]}")
            time.sleep(0.02)
        raise QemuError(f"QEMU printed no pty name within {self.options.start_timeout_s:.0f} s (log: {self.log_path})")


def _kill_quietly(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.kill()
        try:
            proc.wait(3.0)
        except subprocess.TimeoutExpired:
            pass


def _open_raw(path: str) -> int:
    """Open the pty slave non-blocking and make it raw (8 bit, no echo/translation/flow control)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        make_raw(fd)
    except BaseException:
        os.close(fd)
        raise
    return fd
