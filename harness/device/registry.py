"""The one device registry: a `DeviceSpec` (what the user chose) -> a `Device`, for the CLI, the campaign
workers and the pytest plugin alike (as Zephyr twister's adapter factory or labgrid's target factory do).

Kinds (`KINDS`, the `--target` / `--uwb-target` choices):
  host      the host build of the firmware (Linux) on a pty (firmware_sim/build/uwb-fw); `emulator`, its old
            name, is still accepted (TARGET_ALIASES; QEMU is the emulator)
  asan      the same, built with AddressSanitizer + UBSan (firmware_sim/build/uwb-fw-asan): any memory or
            undefined-behaviour error ends the process, which the harness reports as DeviceDied
  serial    a running board on a serial port or pyserial URL (/dev/ttyACM0, rfc2217://host:port, ...)
  qemu      the STM32F405 ELF in QEMU (firmware_sim/build/stm32/uwb-fw.elf); its link (`qemu_link`, --qemu-link) is
            the emulated USART, or "semihosting": uwb-fw-semihost.elf moving whole blocks by ARM semihosting
`create_device` checks the spec (a missing firmware or port is an input error, exit 2, before anything
starts) and builds the device; `open_device` also runs the flash hook, starts it, takes its HELLO once and
checks protocol and model, and always stops it (`started`, which the pytest plugin uses on the
device it created). Device classes are imported only when their kind is
built (the pytest plugin imports this module in every pytest run).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from harness.errors import InputFileNotFound, UsageError
from harness.options import DEFAULT_BAUD, DEVICE_TIMEOUT_S
from harness.paths import DEFAULT_ASAN_FIRMWARE, DEFAULT_FIRMWARE, DEFAULT_STM32_ELF, DEFAULT_STM32_SEMIHOST_ELF

if TYPE_CHECKING:
    from harness.device.base import Device


@dataclass(frozen=True)
class DeviceSpec:
    """What device to use and how to reach it (from the command line, a campaign job or pytest options)."""

    target: str = "host"             # a kind of KINDS, or an alias of one (TARGET_ALIASES)
    port: str | None = None
    baud: int = DEFAULT_BAUD
    firmware: Path | None = None     # None: the kind's default (host binary, ASan binary, STM32 ELF)
    timeout_s: float = DEVICE_TIMEOUT_S  # device silence before giving up; bounds a board's link writes too
    log_dir: Path | None = None
    flash_cmd: str | None = None     # run (shell) before the device starts, e.g. to flash the board
    flash_timeout_s: float = 600.0
    qemu_link: str = "usart"         # qemu only: "usart" or "semihosting" (QEMU_LINKS)
    qemu_icount: bool = True         # qemu only: -icount shift=0 (costs in instructions); False: QEMU's clock
                                     # follows the host's (faster; costs in virtual ns, docs/qemu.md "Speed")

    def __post_init__(self) -> None:
        object.__setattr__(self, "target", canonical_target(self.target))

    def resolved_target(self) -> str:
        """The kind: a port given with the default target means a board."""
        return "serial" if (self.port and self.target == "host") else self.target

    def firmware_path(self) -> Path:
        if self.firmware is not None:
            return Path(self.firmware)
        return default_firmware(self.resolved_target(), self.qemu_link)


@dataclass(frozen=True)
class DeviceKind:
    name: str
    firmware: Path | None                         # default firmware image; None: the device brings its own
    missing_firmware: str                         # how to get the firmware when it is not there
    build: Callable[[DeviceSpec, Path], Device]   # (spec, firmware path) -> an unstarted device


def _host(spec: DeviceSpec, firmware: Path) -> Device:
    from harness.device.host import HostDevice
    return HostDevice(firmware, log_dir=spec.log_dir)


def _serial(spec: DeviceSpec, firmware: Path) -> Device:  # noqa: ARG001 - the board runs what it was flashed with
    from harness.device.serial_device import SerialDevice, SerialDeviceOptions
    if not spec.port:
        raise UsageError("target 'serial' needs a port (--port /dev/ttyACM0, rfc2217://host:port, ...)")
    # the timeout bounds writes too: a board (or serial server) that stops reading fails the run
    return SerialDevice(spec.port, spec.baud, SerialDeviceOptions(write_timeout_s=spec.timeout_s))


def _qemu(spec: DeviceSpec, firmware: Path) -> Device:
    from harness.device.qemu import QemuDevice, QemuOptions, link_build_mismatch
    problem = link_build_mismatch(firmware, spec.qemu_link) if shutil.which("arm-none-eabi-nm") else None
    if problem:
        raise UsageError(problem)    # the wrong build for the link chosen: an input error, nothing started
    return QemuDevice(elf=firmware, log_dir=spec.log_dir, options=QemuOptions(link=spec.qemu_link, icount=spec.qemu_icount))


KINDS: dict[str, DeviceKind] = {
    "host": DeviceKind("host", DEFAULT_FIRMWARE, "firmware binary {path} not found: run `make firmware`", _host),
    "asan": DeviceKind("asan", DEFAULT_ASAN_FIRMWARE,
                       "sanitizer firmware binary {path} not found: run `make firmware`", _host),
    "serial": DeviceKind("serial", None, "", _serial),
    "qemu": DeviceKind("qemu", DEFAULT_STM32_ELF,
                       "firmware ELF {path} not found: build it with `make stm32` or pass --firmware PATH", _qemu),
}
TARGETS = tuple(KINDS)
#: the QEMU device's links (--qemu-link) and the firmware each runs by default: the emulated USART, or ARM
#: semihosting (whole blocks per trap; the emulator-only build, docs/qemu.md)
QEMU_LINKS = {"usart": DEFAULT_STM32_ELF, "semihosting": DEFAULT_STM32_SEMIHOST_ELF}
#: old names still accepted wherever a target is chosen: "emulator" named the host build, while QEMU is the
#: real emulator
TARGET_ALIASES = {"emulator": "host"}
#: what --target / --uwb-target accept
TARGET_CHOICES = (*TARGETS, *TARGET_ALIASES)


def canonical_target(name: str) -> str:
    """The kind an accepted target name means (an alias -> its kind; anything else unchanged)."""
    return TARGET_ALIASES.get(name, name)


def kind_of(spec: DeviceSpec) -> DeviceKind:
    target = spec.resolved_target()
    if target not in KINDS:
        raise UsageError(f"unknown device target {target!r}; choose one of {', '.join(TARGETS)}")
    return KINDS[target]


def create_device(spec: DeviceSpec) -> Device:
    """The device `spec` describes, not started. UsageError for an unknown kind or a missing port,
    FileNotFoundError for a missing firmware image (both input errors: nothing was started). The default host
    firmware, when not built (an installed package), is compiled from the packaged sources on first use
    (harness/firmware_cache.py)."""
    kind = kind_of(spec)
    if spec.qemu_link not in QEMU_LINKS:
        raise UsageError(f"unknown QEMU link {spec.qemu_link!r}; choose one of {', '.join(QEMU_LINKS)}")
    if spec.qemu_link != "usart" and kind.name != "qemu":
        raise UsageError(f"the {spec.qemu_link} link is QEMU's: use it with target qemu, not {kind.name}")
    if not spec.qemu_icount and kind.name != "qemu":
        raise UsageError(f"the QEMU clock option is QEMU's: use it with target qemu, not {kind.name}")
    firmware = spec.firmware_path()
    if kind.name == "host" and spec.firmware is None and not firmware.is_file():
        # no `make firmware` here (an installed package): the build from the shipped sources, cached per user
        from harness.firmware_cache import cached_host_firmware
        firmware = cached_host_firmware()
    if kind.firmware is not None and not firmware.is_file():
        raise InputFileNotFound(kind.missing_firmware.format(path=firmware))
    if kind.name in ("host", "asan") and not os.access(firmware, os.X_OK):    # --firmware naming a data file
        raise UsageError(f"firmware binary {firmware} is not executable (not a firmware build?)")
    return kind.build(spec, firmware)


def default_firmware(target: str, qemu_link: str = "usart") -> Path:
    """The firmware image a kind runs when none is given (the host binary for a board: unused); for qemu, the
    build its link needs."""
    if target == "qemu" and qemu_link in QEMU_LINKS:
        return QEMU_LINKS[qemu_link]
    kind = KINDS.get(target)
    return kind.firmware if kind is not None and kind.firmware is not None else DEFAULT_FIRMWARE


@contextmanager
def started(device: Device, timeout_s: float, expected_model_hash: int | None = None) -> Iterator[Device]:
    """Start the device, take its HELLO (once: `device.identity`), check protocol and model; always stop it."""
    device.start()
    try:
        device.hello(timeout=timeout_s)
        device.check(expected_model_hash=expected_model_hash)
        yield device
    finally:
        device.stop()


@contextmanager
def open_device(spec: DeviceSpec, expected_model_hash: int | None = None) -> Iterator[Device]:
    """The device of `spec`, after the flash hook, `started`."""
    device = create_device(spec)
    if spec.flash_cmd:
        from harness.device.flash import run_flash_command
        log = Path(spec.log_dir) / "flash.log" if spec.log_dir else None
        run_flash_command(spec.flash_cmd, spec.flash_timeout_s, log)
    with started(device, spec.timeout_s, expected_model_hash) as dev:
        yield dev
