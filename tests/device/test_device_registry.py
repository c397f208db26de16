"""The device registry: every kind (host emulator, its sanitizer build, serial board, QEMU) comes from one
`create_device(DeviceSpec)`, which the CLI, the campaign workers and the pytest plugin all use; an unknown
kind or a missing firmware/port is a clear input error before anything starts."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import pytest

from harness.device.host import HostDevice
from harness.device.qemu import QemuDevice, QemuOptions
from harness.device.registry import (KINDS, TARGET_CHOICES, TARGETS, DeviceSpec, create_device, default_firmware,
                                     open_device)
from harness.device.serial_device import SerialDevice
from harness.errors import InputError, UsageError
from harness.paths import DEFAULT_ASAN_FIRMWARE, DEFAULT_FIRMWARE, DEFAULT_STM32_ELF

ROOT = Path(__file__).resolve().parents[2]


def _image(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    path.write_bytes(b"\x7fELF")
    path.chmod(0o755)
    return path


def test_every_kind_comes_from_the_registry(tmp_path: Path) -> None:
    assert TARGETS == ("host", "asan", "serial", "qemu")
    host = create_device(DeviceSpec(firmware=_image(tmp_path, "uwb-fw"), log_dir=tmp_path))
    asan = create_device(DeviceSpec(target="asan", firmware=_image(tmp_path, "uwb-fw-asan")))
    board = create_device(DeviceSpec(target="serial", port="socket://127.0.0.1:9", baud=921600, timeout_s=3.0))
    qemu = create_device(DeviceSpec(target="qemu", firmware=_image(tmp_path, "uwb-fw.elf"), log_dir=tmp_path))
    assert isinstance(host, HostDevice) and host.binary.name == "uwb-fw" and host.log_dir == tmp_path
    assert isinstance(asan, HostDevice) and asan.binary.name == "uwb-fw-asan"
    assert isinstance(board, SerialDevice) and (board.url, board.baud) == ("socket://127.0.0.1:9", 921600)
    assert board.options.write_timeout_s == 3.0          # the device timeout bounds a board's writes too
    assert isinstance(qemu, QemuDevice) and qemu.elf.name == "uwb-fw.elf"
    # a port with the default target means a board
    assert isinstance(create_device(DeviceSpec(port="loop://")), SerialDevice)
    assert default_firmware("host") == DEFAULT_FIRMWARE and default_firmware("asan") == DEFAULT_ASAN_FIRMWARE
    assert default_firmware("qemu") == DEFAULT_STM32_ELF
    assert DeviceSpec(target="qemu").firmware_path() == DEFAULT_STM32_ELF


def test_emulator_is_the_old_name_of_the_host_build(tmp_path: Path) -> None:
    """`emulator` named the host build (QEMU is the emulator): still accepted by the registry, the CLI's
    --target and the plugin's --uwb-target, as host."""
    from harness.cli import build_parser
    from harness.device_args import device_spec
    assert DeviceSpec(target="emulator").target == "host" and DeviceSpec().target == "host"
    assert isinstance(create_device(DeviceSpec(target="emulator", firmware=_image(tmp_path, "uwb-fw"))), HostDevice)
    args = build_parser().parse_args(["run", "--target", "emulator"])
    assert device_spec(args).resolved_target() == "host"
    assert "emulator" in TARGET_CHOICES and "emulator" not in TARGETS


def test_qemu_clock_option(tmp_path: Path) -> None:
    """--qemu-clock: icount (default, -icount shift=0: costs are instruction counts) or host (no -icount)."""
    from harness.cli import build_parser
    from harness.device_args import device_spec
    parse = build_parser().parse_args
    assert device_spec(parse(["run", "--target", "qemu"])).qemu_icount
    spec = device_spec(parse(["run", "--target", "qemu", "--qemu-clock", "host"]))
    assert not spec.qemu_icount
    qemu = create_device(replace(spec, firmware=_image(tmp_path, "uwb-fw.elf")))
    assert isinstance(qemu, QemuDevice) and not qemu.options.icount
    cmd = qemu.options.command(Path("fw.elf"), tmp_path / "mon", tmp_path / "ser")
    assert "-icount" not in cmd and "-icount" in QemuOptions().command(Path("fw.elf"), tmp_path / "mon", tmp_path / "s")


def test_bad_choices_are_input_errors_naming_the_fix(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="unknown device target 'jtag'; choose one of host, asan, serial, qemu"):
        create_device(DeviceSpec(target="jtag"))
    assert issubclass(UsageError, InputError)              # exit code 2, not a device failure
    with pytest.raises(UsageError, match="needs a port"):
        create_device(DeviceSpec(target="serial"))
    with pytest.raises(FileNotFoundError, match=r"firmware binary .*nope not found: run `make firmware`"):
        create_device(DeviceSpec(firmware=tmp_path / "nope"))
    data = tmp_path / "anchors.csv"                        # `--firmware` naming a data file: exit 2, not 3
    data.write_text("constellation,anchor_id,x_m,y_m,z_m\n")
    with pytest.raises(UsageError, match=r"firmware binary .*anchors.csv is not executable"):
        create_device(DeviceSpec(firmware=data))
    with pytest.raises(FileNotFoundError, match="make stm32"):
        create_device(DeviceSpec(target="qemu", firmware=tmp_path / "nope.elf"))
    with pytest.raises(UsageError), open_device(DeviceSpec(target="jtag")):
        pass


def test_the_cli_the_workers_and_the_plugin_construct_devices_only_through_it() -> None:
    """No module outside harness/device/ builds a device class itself (the QEMU start-up bench measures
    QemuOptions transports and is the one exception)."""
    pattern = re.compile(r"\b(HostDevice|SerialDevice|QemuDevice)\(")
    offenders = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "harness").rglob("*.py"))
                 if "device" not in p.relative_to(ROOT).parts and p.relative_to(ROOT).as_posix() != "harness/bench/qemu_start.py"
                 and pattern.search(p.read_text())]
    assert offenders == []
    for module in ("harness/pytest_plugin.py", "harness/campaign/worker.py", "harness/run/single.py",
                   "harness/run/demo.py", "harness/closedloop/fly.py", "harness/device_args.py"):
        assert "harness.device.registry import" in (ROOT / module).read_text(), module
    assert set(KINDS) == set(TARGETS)


@pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")
def test_open_device_says_hello_once(tmp_path: Path) -> None:
    with open_device(DeviceSpec(log_dir=tmp_path)) as dev:
        assert dev.channel.next_seq == 1                   # one HELLO; check() used its reply
        assert dev.identity.target == "host" and dev.identity.proto_version >= 1
    assert not dev.alive()


@pytest.mark.skipif(not DEFAULT_ASAN_FIRMWARE.exists(), reason="sanitizer firmware not built (make firmware)")
def test_the_sanitizer_build_is_a_kind(tmp_path: Path) -> None:
    with open_device(DeviceSpec(target="asan", log_dir=tmp_path)) as dev:
        assert isinstance(dev, HostDevice) and dev.binary == DEFAULT_ASAN_FIRMWARE
        assert dev.channel.stats(timeout=5.0).frames_ok == 2     # the HELLO and this STATS_REQ
