"""QemuDevice: the STM32F405 build of the firmware running in QEMU (`-M netduinoplus2`).

Start-up follows the measured recipe (shared/reference/qemu-cortex-m4.md):
  1. qemu-system-arm ... -serial pty -S   (CPU halted, USART1 = serial0 on a fresh pty),
  2. parse "char device redirected to /dev/pts/N" from QEMU's output,
  3. open the pty raw (no echo, no CR/LF translation, no flow control),
  4. wait until QEMU has noticed the open slave (it polls once per second; bytes the guest writes
     before that are dropped), then `cont` on the HMP monitor socket.
With `-icount shift=0` every guest instruction advances virtual time by 1 ns and TIM2 (clocked at a
fixed 1 GHz) counts instructions, so the firmware's per-stage costs are exact instruction counts and
identical from run to run. Every wait has a timeout; stop() always reaps QEMU.
"""

from __future__ import annotations

import errno
import os
import re
import select
import shutil
import socket
import subprocess
import tempfile
import termios
import time
import tty
from dataclasses import dataclass
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_ELF = REPO_ROOT / "firmware_sim" / "build" / "stm32" / "uwb-fw.elf"

_PTY_RE = re.compile(r"char device redirected to (/dev/pts/\d+) \(label (\w+)\)")
_PROMPT = b"(qemu) "
# `-serial` index -> USART base address on the STM32F405 SoC model (hw/arm/stm32f405_soc.c).
USART_BASES = (0x40011000, 0x40004400, 0x40004800, 0x40004C00, 0x40005000, 0x40011400, 0x40007800)
_USART_CR1 = 0x0C
_CR1_UE_RE = (1 << 13) | (1 << 2)
_ANSI_RE = re.compile(rb"\x1b\[[0-9;]*[A-Za-z]")


class QemuError(RuntimeError):
    """QEMU could not be started, or stopped answering its monitor."""


def qemu_binary() -> str | None:
    return shutil.which("qemu-system-arm")


@dataclass(frozen=True)
class QemuOptions:
    machine: str = "netduinoplus2"
    icount: bool = True              # -icount shift=0: 1 ns virtual time per instruction (deterministic)
    serial_index: int = 0            # 0 = USART1 (the firmware's default link), 2 = USART3
    start_timeout_s: float = 10.0    # QEMU must print the pty name within this
    settle_s: float = 1.2            # > QEMU's 1 s pty poll: time for it to see the opened slave
    stop_timeout_s: float = 3.0
    qemu: str = "qemu-system-arm"

    def command(self, elf: Path, monitor_path: Path) -> list[str]:
        cmd = [self.qemu, "-M", self.machine, "-display", "none", "-nodefaults",
               "-monitor", f"unix:{monitor_path},server=on,wait=off"]
        # serial0..serialN: only the link's USART gets the pty, the ones before it are null.
        cmd += ["-serial", "null"] * self.serial_index + ["-serial", "pty"]
        cmd += ["-kernel", str(elf), "-S"]
        if self.icount:
            cmd += ["-icount", "shift=0,align=off"]
        return cmd


class QemuProcess:
    """One QEMU instance with the guest's link USART on a raw pty and an HMP monitor socket."""

    def __init__(self, elf: Path, log_path: Path, options: QemuOptions = QemuOptions()) -> None:
        self.elf = Path(elf)
        self.log_path = Path(log_path)
        self.options = options
        self.proc: subprocess.Popen[bytes] | None = None
        self.pty_path: str | None = None
        self.fd: int = -1
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._mon: socket.socket | None = None
        self._log = None

    # ---------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        if not self.elf.is_file():
            raise QemuError(f"firmware {self.elf} not found: build it with `make -C firmware_sim/stm32`")
        if shutil.which(self.options.qemu) is None:
            raise QemuError(f"{self.options.qemu} not found: run scripts/ensure_arm_tools.sh")
        self._tmp = tempfile.TemporaryDirectory(prefix="uwb-qemu-")
        mon_path = Path(self._tmp.name) / "monitor.sock"
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        cmd = self.options.command(self.elf, mon_path)
        self._log.write(("$ " + " ".join(cmd) + "\n").encode())
        self._log.flush()
        try:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self._log,
                                         stderr=subprocess.STDOUT, start_new_session=True)
            self.pty_path = self._wait_for_pty()
            self.fd = _open_raw(self.pty_path)
            self._mon = self._connect_monitor(mon_path)
            # QEMU learns that the slave is open on its next 1 s poll; until then the guest's first
            # bytes would be dropped. The CPU is still halted (-S), so simply wait, then run.
            time.sleep(self.options.settle_s)
            self.monitor("cont")
            self._wait_for_receiver()
        except BaseException:
            self.stop()
            raise

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        proc, self.proc = self.proc, None
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
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
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


def _open_raw(path: str) -> int:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[0] &= ~(termios.IXON | termios.IXOFF | termios.ICRNL | termios.INLCR | termios.IGNCR)
        attrs[1] &= ~termios.OPOST
        attrs[3] &= ~(termios.ECHO | termios.ICANON | termios.ISIG | termios.IEXTEN)
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
    except BaseException:
        os.close(fd)
        raise
    return fd


class PtyLink:
    """Byte transport over the raw pty: write(bytes) and read(max_bytes, timeout)."""

    def __init__(self, fd: int, write_timeout_s: float = 10.0) -> None:
        self.fd = fd
        self.write_timeout_s = write_timeout_s

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + self.write_timeout_s
        while view:
            try:
                n = os.write(self.fd, view)
                view = view[n:]
                continue
            except BlockingIOError:
                pass
            except OSError as exc:
                raise _link_closed(f"pty write failed: {exc}") from exc
            left = deadline - time.monotonic()
            if left <= 0:
                raise _link_timeout(f"pty write blocked for {self.write_timeout_s:.1f} s "
                                    f"({len(view)} bytes left): the guest stopped reading")
            select.select([], [self.fd], [], min(left, 0.05))

    def read(self, max_bytes: int, timeout: float) -> bytes:
        r, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
        if not r:
            return b""
        try:
            return os.read(self.fd, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise _link_closed("pty closed (QEMU exited)") from exc
            raise _link_closed(f"pty read failed: {exc}") from exc

    def close(self) -> None:
        pass  # the fd belongs to QemuProcess


def _link_closed(msg: str) -> Exception:
    try:
        from harness.errors import LinkClosed
        return LinkClosed(msg)
    except ImportError:  # pragma: no cover - errors.py is written concurrently
        return ConnectionError(msg)


def _link_timeout(msg: str) -> Exception:
    try:
        from harness.errors import DeviceTimeout
        return DeviceTimeout(msg)
    except ImportError:  # pragma: no cover
        return TimeoutError(msg)
