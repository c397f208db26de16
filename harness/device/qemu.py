"""QemuDevice: the STM32F405 build of the firmware running in QEMU (`-M netduinoplus2`).

Start-up (serial="socket", the default):
  1. qemu-system-arm ... -chardev socket,path=S,server=on,wait=off -serial chardev:... -S
     (CPU halted, USART1 = serial0 on a listening unix socket),
  2. connect to S, then to the HMP monitor socket,
  3. wait until the monitor's `info chardev` shows the serial socket connected (QEMU accepts in its main
     loop: milliseconds), then `cont`.
With link="semihosting" (QemuOptions.link) the guest is the emulator build uwb-fw-semihost.elf and its link is
two FIFOs in QEMU's working directory, moved in whole blocks by ARM semihosting (SYS_READ/SYS_WRITE) instead of
one byte per QEMU main-loop iteration: the same frames, the same firmware core (docs/qemu.md). The ELF must match
the link: each build is recognised by its symbols before QEMU starts.
The pty recipe of shared/reference/qemu-cortex-m4.md (serial="pty": `-serial pty`, parse "char device
redirected to /dev/pts/N", open the pty raw, then wait 1.2 s because QEMU notices an opened slave only on
its next 1 s poll and drops the guest's bytes until then) is kept as an option; the socket saves that
wait on every start (docs/qemu.md).
With `-icount shift=0` every guest instruction advances virtual time by 1 ns and TIM2 (clocked at a
fixed 1 GHz) counts instructions, so the firmware's per-stage costs are exact instruction counts and
identical from run to run. Every wait has a timeout; stop() always reaps QEMU.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

from harness.device.base import Device
from harness.device.identity import DeviceIdentity
from harness.device.process_log import exit_error, new_log_path, remove_tmp_dir
from harness.device.qemu_process import QemuError, QemuOptions, QemuProcess
from harness.errors import DeviceDied, DeviceError
from harness.link.base import Link
from harness.link.qemu_link import QemuPtyLink
from harness.paths import DEFAULT_STM32_ELF
from protocol.messages import CostUnit

DEFAULT_ELF = DEFAULT_STM32_ELF
#: a symbol only the semihosting link's build defines (stm32/semihost_link.c)
SEMIHOST_SYMBOL = "semihost_link_open"


class QemuDevice(Device):
    """The STM32F405 firmware ELF in QEMU, serving the protocol on USART1 (or USART3, serial_index=2)."""

    def __init__(self, elf: Path | str = DEFAULT_ELF, log_dir: Path | str | None = None, icount: bool = True,
                 options: QemuOptions | None = None) -> None:
        super().__init__()
        self.elf = Path(elf)
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.options = options if options is not None else QemuOptions(icount=icount)
        self.log_path: Path | None = None
        self.returncode: int | None = None
        self._proc: QemuProcess | None = None
        self._link: QemuPtyLink | None = None
        self._tmp_log_dir: str | None = None

    @property
    def name(self) -> str:
        pid = f" pid {self._proc.proc.pid}" if self._proc is not None and self._proc.proc is not None else ""
        return f"qemu {self.options.machine} {self.elf.name}{pid}"

    @property
    def process(self) -> QemuProcess:
        return self._running(self._proc)

    @property
    def link(self) -> Link:
        return self._running(self._link)

    def start(self) -> None:
        self._not_running(self._proc)
        if not self.elf.is_file():
            raise DeviceError(f"firmware {self.elf} not found: build it with `make stm32` "
                              "(toolchain: scripts/ensure_arm_tools.sh)")
        if shutil.which(self.options.qemu) is None:
            raise DeviceError(f"{self.options.qemu} not found: run scripts/ensure_arm_tools.sh")
        self._check_link_build()
        self.returncode = None
        self.log_path = self._new_log_path()
        proc = QemuProcess(self.elf, self.log_path, self.options)
        try:
            proc.start()
        except QemuError as exc:
            self._remove_tmp_log()
            raise DeviceError(f"cannot start QEMU for {self.elf.name}: {exc}") from exc
        assert proc.serial_name is not None
        self._proc = proc
        self._link = QemuPtyLink(proc.fd, proc.serial_name, write_fd=proc.write_fd)

    @property
    def identity(self) -> DeviceIdentity:
        """Without -icount TIM2 counts QEMU's virtual ns, which then follow the host's clock: the costs are
        nanoseconds, whatever unit the firmware (which cannot tell) names in its HELLO_REPLY."""
        identity = super().identity
        if self.options.icount:
            return identity
        return replace(identity, cost_unit=int(CostUnit.NANOSECONDS))

    def _check_link_build(self) -> None:
        problem = link_build_mismatch(self.elf, self.options.link)
        if problem:
            raise DeviceError(problem)

    def alive(self) -> bool:
        return self._proc is not None and self._proc.alive()

    def died(self, grace_s: float = 0.0) -> DeviceDied | None:
        proc = self._proc
        if proc is None or proc.proc is None:
            return None
        try:
            code = proc.proc.wait(max(0.0, grace_s)) if grace_s > 0 else proc.proc.poll()
        except subprocess.TimeoutExpired:
            code = None
        if code is None:
            return None
        return exit_error(self.name, code, self.log_tail(), self.log_path, self._tmp_log_dir is None)

    def stop(self) -> int | None:
        proc, self._proc = self._proc, None
        if self._link is not None:
            self._link.close()
            self._link = None
        if proc is not None:
            popen = proc.proc
            proc.stop()
            self.returncode = popen.returncode if popen is not None else None
        self._remove_tmp_log()
        return self.returncode

    def log_tail(self, lines: int = 30) -> str:
        if self.log_path is None:
            return ""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def stack_high_water(self) -> int:
        """Bytes of the main stack ever used (the firmware paints it at reset), read via the monitor."""
        proc = self.process
        if self.options.link == "semihosting":
            raise DeviceError("the stack high-water mark is read through QEMU's monitor, which does not answer while "
                              "a semihosting guest waits for input: measure it with the USART link")
        lo, size = _symbol_range(self.elf, "_sstack", "_estack")
        words = proc.read_words(lo, size // 4)
        untouched = next((i for i, w in enumerate(words) if w != 0xA5A5A5A5), len(words))
        return size - 4 * untouched

    def _new_log_path(self) -> Path:
        path, self._tmp_log_dir = new_log_path(self.log_dir, "uwb-qemu-", f"qemu-{self.elf.stem}")
        return path

    def _remove_tmp_log(self) -> None:
        tmp, self._tmp_log_dir = self._tmp_log_dir, None
        if remove_tmp_dir(tmp):
            self.log_path = None


def link_build_mismatch(elf: Path, link: str) -> str | None:
    """Why `elf` cannot serve `link`, or None: the semihosting link needs the emulator build and the USART link
    the other; a mismatch would only show as a silent device, so it is refused with the fix before QEMU starts.
    None too when the symbols cannot be read (no ELF: QEMU's start reports that)."""
    try:
        semihost_build = SEMIHOST_SYMBOL in _elf_symbols(elf)
    except DeviceError:
        return None
    if link == "semihosting" and not semihost_build:
        return (f"{elf.name} has no semihosting link: the QEMU semihosting link runs uwb-fw-semihost.elf "
                "(`make stm32`; docs/qemu.md)")
    if link != "semihosting" and semihost_build:
        return (f"{elf.name} is the semihosting build: run it with the semihosting link (--qemu-link semihosting), "
                "or the USART link with uwb-fw.elf")
    return None


def _elf_symbols(elf: Path) -> dict[str, int]:
    nm = shutil.which("arm-none-eabi-nm")
    if nm is None:
        raise DeviceError("arm-none-eabi-nm not found (scripts/ensure_arm_tools.sh)")
    try:
        out = subprocess.run([nm, str(elf)], capture_output=True, text=True, timeout=30, check=True).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        raise DeviceError(f"cannot read the symbols of {elf}: {exc}") from exc
    return {parts[2]: int(parts[0], 16) for parts in (ln.split() for ln in out.splitlines()) if len(parts) == 3}


def _symbol_range(elf: Path, lo_sym: str, hi_sym: str) -> tuple[int, int]:
    syms = _elf_symbols(elf)
    if lo_sym not in syms or hi_sym not in syms:
        raise DeviceError(f"{elf.name} has no {lo_sym}/{hi_sym} symbols")
    return syms[lo_sym], syms[hi_sym] - syms[lo_sym]
