"""pytest plugin `uwb_hil` (entry point pytest11): device options, fixtures and markers.

Options (group "uwb-hil"), each also a fixture of the same name without dashes that a test can
override by indirect parametrization (value resolution: indirect param -> command line -> default):

  --uwb-port      pyserial URL or device path of a real board (/dev/ttyACM0, rfc2217://host:port, ...)
  --uwb-baud      baud rate (115200)
  --uwb-target    emulator | serial | qemu (emulator, or serial when --uwb-port is given)
  --uwb-firmware  host firmware binary (<repo>/firmware_sim/build/uwb-fw)
  --uwb-timeout   seconds to wait for the device (5)

`uwb_device` yields a started, HELLO-checked device and always stops it. Marker `hardware`: the test
needs a real board and is skipped unless --uwb-port or --uwb-target serial is given.

This module is imported by every pytest run in the environment: it imports nothing heavy at the top.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

import pytest

if TYPE_CHECKING:
    from harness.device.base import Device

TARGETS = ("emulator", "serial", "qemu")
DEFAULT_BAUD = 115200
DEFAULT_TIMEOUT_S = 5.0
_REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_FIRMWARE = _REPO_ROOT / "firmware_sim" / "build" / "uwb-fw"


@dataclass(frozen=True)
class DeviceChoice:
    """What `uwb_device` starts, resolved from the option fixtures."""

    target: str
    port: str | None
    baud: int
    firmware: Path
    timeout_s: float


# --------------------------------------------------------------------------------------- options
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("uwb-hil", "uwb-hil device under test")
    group.addoption("--uwb-port", default=None,
                    help="pyserial URL or device path of a real board; when given, tests run against it")
    group.addoption("--uwb-baud", type=int, default=None, help=f"baud rate of --uwb-port (default {DEFAULT_BAUD})")
    group.addoption("--uwb-target", choices=TARGETS, default=None,
                    help="device kind (default: emulator, or serial when --uwb-port is given)")
    group.addoption("--uwb-firmware", default=None,
                    help=f"host firmware binary for the emulator target (default {DEFAULT_FIRMWARE})")
    group.addoption("--uwb-timeout", type=float, default=None,
                    help=f"seconds to wait for the device (default {DEFAULT_TIMEOUT_S:g})")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "hardware: needs a real board (--uwb-port or --uwb-target serial)")


def _hardware_selected(config: pytest.Config) -> bool:
    return bool(config.getoption("uwb_port")) or config.getoption("uwb_target") == "serial"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if _hardware_selected(config):
        return
    skip = pytest.mark.skip(reason="needs a real board: give --uwb-port (or --uwb-target serial)")
    for item in items:
        if item.get_closest_marker("hardware") is not None:
            item.add_marker(skip)


def pytest_report_header(config: pytest.Config) -> str:
    port = config.getoption("uwb_port")
    target = config.getoption("uwb_target") or ("serial" if port else "emulator")
    if target == "serial":
        return f"uwb-hil: target serial, port {port}, baud {config.getoption('uwb_baud') or DEFAULT_BAUD}"
    if target == "emulator":
        fw = Path(config.getoption("uwb_firmware") or DEFAULT_FIRMWARE)
        return f"uwb-hil: target emulator, firmware {fw}{'' if fw.exists() else ' (not built)'}"
    return f"uwb-hil: target {target}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[Any]:
    """A failing test that used `uwb_device` gets the tail of the device log in its report."""
    outcome: Any = yield
    report: pytest.TestReport = outcome.get_result()
    device = getattr(item, "funcargs", {}).get("uwb_device")
    tail = getattr(device, "log_tail", None)
    if report.failed and call.when == "call" and callable(tail):
        text = tail()
        if text:
            report.sections.append(("uwb device log (tail)", text))


# ------------------------------------------------------------------------------ option fixtures
def _param_or_option(request: pytest.FixtureRequest, option: str, default: Any) -> Any:
    """Indirect parametrization wins, then the command line, then the default."""
    if hasattr(request, "param"):
        return request.param
    value = request.config.getoption(option)
    return default if value is None else value


@pytest.fixture
def uwb_port(request: pytest.FixtureRequest) -> str | None:
    port = _param_or_option(request, "uwb_port", None)
    return None if port is None else str(port)


@pytest.fixture
def uwb_baud(request: pytest.FixtureRequest) -> int:
    return int(_param_or_option(request, "uwb_baud", DEFAULT_BAUD))


@pytest.fixture
def uwb_target(request: pytest.FixtureRequest, uwb_port: str | None) -> str:
    target = str(_param_or_option(request, "uwb_target", "serial" if uwb_port else "emulator"))
    if target not in TARGETS:
        raise pytest.UsageError(f"uwb_target must be one of {TARGETS}, got {target!r}")
    return target


@pytest.fixture
def uwb_firmware(request: pytest.FixtureRequest) -> Path:
    return Path(_param_or_option(request, "uwb_firmware", DEFAULT_FIRMWARE))


@pytest.fixture
def uwb_timeout(request: pytest.FixtureRequest) -> float:
    return float(_param_or_option(request, "uwb_timeout", DEFAULT_TIMEOUT_S))


@pytest.fixture
def uwb_expected_model_hash(request: pytest.FixtureRequest) -> int | None:
    """Model hash the device must report; None = do not check. Override in a conftest or by param."""
    return getattr(request, "param", None)


# ------------------------------------------------------------------------------- device fixture
def _make_device(choice: DeviceChoice, log_dir: Path) -> Device:
    if choice.target == "emulator":
        from harness.device.emulator import EmulatorDevice

        if not choice.firmware.is_file():
            pytest.fail(f"firmware binary {choice.firmware} not found: run `make firmware` "
                        f"(or pass --uwb-firmware)", pytrace=False)
        return EmulatorDevice(choice.firmware, log_dir=log_dir)
    if choice.target == "serial":
        from harness.device.serial_device import SerialDevice

        if not choice.port:
            pytest.fail("target 'serial' needs --uwb-port (a device path or pyserial URL)", pytrace=False)
        return SerialDevice(choice.port, choice.baud)
    from harness.device.qemu import QemuDevice

    return QemuDevice(log_dir=log_dir)


def _hello_properties(device: Device) -> dict[str, str]:
    hello = device.last_hello
    if hello is None:
        return {}
    return {
        "uwb_fw_version": f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}",
        "uwb_build_id": _ascii(hello.build_id),
        "uwb_model_hash": f"{hello.model_hash:#018x}",
        "uwb_device_target": _ascii(hello.target),
        "uwb_proto_version": str(hello.proto_version),
        "uwb_layouts": f"twr={hello.layout_twr} tdoa={hello.layout_tdoa}",
    }


def _ascii(raw: bytes) -> str:
    return raw.rstrip(b"\x00").decode("ascii", errors="replace")


@pytest.fixture
def uwb_device(request: pytest.FixtureRequest, uwb_target: str, uwb_port: str | None, uwb_baud: int,
               uwb_firmware: Path, uwb_timeout: float, uwb_expected_model_hash: int | None,
               tmp_path_factory: pytest.TempPathFactory) -> Iterator[Device]:
    """A started device whose HELLO was checked (protocol version, optional model hash).

    The HELLO (firmware version, build id, model hash, target), link, exit code and log path become
    the test's user properties (JUnit <properties>). They are appended directly rather than through
    the `record_property` fixture, which warns on every test under the default xunit2 family.
    """
    choice = DeviceChoice(uwb_target, uwb_port, uwb_baud, uwb_firmware, uwb_timeout)

    def record_property(name: str, value: object) -> None:
        request.node.user_properties.append((name, value))

    log_dir = tmp_path_factory.mktemp("uwb-device", numbered=True)
    device = _make_device(choice, log_dir)
    record_property("uwb_target", choice.target)
    try:
        device.start()
        record_property("uwb_link", device.link.name)
        device.hello(timeout=choice.timeout_s)
        device.check(expected_model_hash=uwb_expected_model_hash)
        for key, value in _hello_properties(device).items():
            record_property(key, value)
        yield device
    finally:
        exit_code = device.stop()
        if exit_code is not None:
            record_property("uwb_exit_code", exit_code)
        log_path = getattr(device, "log_path", None)
        if log_path is not None:
            record_property("uwb_log", str(log_path))
