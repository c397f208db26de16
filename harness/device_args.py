"""The device options every command shares (--target, --port, --firmware, ...): their parser group, the
DeviceSpec they describe, and the device identity as printed. Used by the CLI modules of `run`, `demo` and
`fly`; it lives outside them so that no module imports from a CLI module."""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace
from pathlib import Path
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from harness import options
from harness.device.registry import TARGET_CHOICES, DeviceSpec
from harness.errors import UsageError
from harness.paths import DEFAULT_FIRMWARE, DEFAULT_STM32_ELF, output_path


def add_device_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("device")
    g.add_argument("--target", choices=TARGET_CHOICES, default=None,
                   help="host (the firmware built for this machine, on a pty; the default without a port; "
                        "'emulator' is its old name), asan (the same built with ASan+UBSan), serial (a board on "
                        "--port; the default with one), qemu (the STM32F405 build in QEMU)")
    g.add_argument("--port", help="pyserial URL or device of a real board: /dev/ttyACM0, rfc2217://host:port "
                                  "(default: $UWB_HIL_PORT; `uwb-hil ports` lists this machine's ports)")
    g.add_argument("--port-serial", metavar="SERIAL",
                   help="the board whose USB serial number is SERIAL (see `uwb-hil ports`), whatever its path")
    g.add_argument("--baud", type=options.baud, default=None,
                   help=f"serial line speed of a board on --port (default {options.DEFAULT_BAUD})")
    g.add_argument("--firmware", default=None,
                   help=f"firmware to run: the host binary for host (default {DEFAULT_FIRMWARE}), "
                        f"the STM32F405 ELF for qemu (default {DEFAULT_STM32_ELF})")
    g.add_argument("--qemu-link", choices=("usart", "semihosting"), default="usart",
                   help="qemu only: the guest's link, the emulated USART (as a board's serial line; default) or "
                        "semihosting (the emulator build uwb-fw-semihost.elf moving whole blocks: the fastest "
                        "replays; docs/qemu.md)")
    g.add_argument("--qemu-clock", choices=("icount", "host"), default="icount",
                   help="qemu only: icount (-icount shift=0: every guest instruction is 1 ns of virtual time, the "
                        "RESULT costs are exact instruction counts; default) or host (QEMU's virtual clock follows "
                        "the host's: no instruction counting, costs in ns of that clock; docs/qemu.md \"Speed\")")
    g.add_argument("--timeout", type=options.timeout_s, default=options.DEVICE_TIMEOUT_S,
                   help="seconds of device silence before giving up (> 0)")
    g.add_argument("--log-dir", help="where device logs go")
    g.add_argument("--flash-cmd", metavar="CMD",
                   help="shell command run before the device starts (e.g. flash the board: "
                        "\"st-flash write build/uwb-fw.bin 0x8000000\"); a failure stops the run")
    add_labgrid_options(g)


def add_labgrid_options(g: Any) -> None:
    """--labgrid-place NAME (the board of a labgrid place, [farm] extra) and its coordinator."""
    g.add_argument("--labgrid-place", "--uwb-labgrid-place", dest="labgrid_place", metavar="NAME", default=None,
                   help="acquire this labgrid place and use its serial port (NetworkSerialPort, RFC 2217); "
                        "released at the end, also on errors and Ctrl-C ([farm] extra)")
    g.add_argument("--labgrid-coordinator", metavar="HOST:PORT", default=None,
                   help="labgrid coordinator (default $LG_COORDINATOR, else 127.0.0.1:20408)")


@contextmanager
def labgrid_lease(args: argparse.Namespace) -> Iterator[None]:
    """With --labgrid-place: the place acquired for the command's lifetime, its serial port as the command's
    --port (a list of ports: one more board), the target serial; without it, nothing."""
    name = getattr(args, "labgrid_place", None)
    if not name:
        yield
        return
    from harness.device.labgrid import PlaceOptions, place
    with place(PlaceOptions(name=name, coordinator=getattr(args, "labgrid_coordinator", None))) as lease:
        if isinstance(getattr(args, "port", None), list):
            args.port = [*args.port, lease.url]
        else:
            args.port, args.target = lease.url, "serial"
        yield


def device_spec(args: argparse.Namespace) -> DeviceSpec:
    from harness.link.ports import default_port, port_for_serial
    if getattr(args, "flash_cmd", None):
        log_to_stderr("uwb_hil.flash")     # the flash command's output belongs in the run's log
    port = args.port
    if getattr(args, "port_serial", None):
        if port:
            raise UsageError("give --port or --port-serial, not both")
        port = port_for_serial(args.port_serial)
    if port and args.target not in (None, "serial"):       # a board's port with a started target: one of them
        raise UsageError(f"--target {args.target} starts its own device: --port / --port-serial name a board "
                         "(--target serial); give one of them")
    if port is None and args.target in (None, "serial"):
        port = default_port()           # $UWB_HIL_PORT; an explicit --target host/qemu ignores it
    target = args.target or ("serial" if port else "host")
    if target != "serial" and getattr(args, "baud", None) is not None:
        raise UsageError(f"--baud is the line speed of a board on --port; --target {target} starts its own device")
    if target == "serial" and args.firmware:      # a board runs what it was flashed with (flash it: --flash-cmd)
        raise UsageError("--firmware names the image a started target runs (host, asan, qemu); a board on "
                         "--port runs what it was flashed with (--flash-cmd flashes it first)")
    return DeviceSpec(target=target, port=port, baud=args.baud or options.DEFAULT_BAUD,
                      firmware=Path(args.firmware) if args.firmware else None,
                      timeout_s=args.timeout,
                      log_dir=output_path(args.log_dir, "--log-dir", directory=True) if args.log_dir else None,
                      flash_cmd=getattr(args, "flash_cmd", None) or None,
                      qemu_link=getattr(args, "qemu_link", None) or "usart",
                      qemu_icount=getattr(args, "qemu_clock", "icount") != "host")


def log_to_stderr(name: str) -> None:
    logger = logging.getLogger(name)
    if not logger.handlers:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("uwb-hil: %(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)


def model_device_spec(args: argparse.Namespace) -> tuple[DeviceSpec, int | None]:
    """The device spec, and the model hash the device must report when --model is given. On the host build
    the firmware is (re)built with that model; a board or QEMU image must already carry it."""
    spec = device_spec(args)
    if not getattr(args, "model", None):
        return spec, None
    from harness.biasnet.network import BiasModel
    model = BiasModel.load(Path(args.model))
    if spec.resolved_target() == "host" and spec.firmware_path() == DEFAULT_FIRMWARE:
        from harness.firmware_build import firmware_for
        spec = replace(spec, firmware=firmware_for(model))
    return spec, model.hash

