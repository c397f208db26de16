"""pytest plugin `uwb_hil` (entry point pytest11): device options, fixtures and markers.

Options (group "uwb-hil"), each also a fixture of the same name without dashes that a test can
override by indirect parametrization (value resolution: indirect param -> command line -> default):

  --uwb-port      pyserial URL or device path of a real board (/dev/ttyACM0, rfc2217://host:port, ...);
                  default $UWB_HIL_PORT
  --uwb-port-serial  the board with this USB serial number (`uwb-hil ports`), whatever its device path
  --uwb-baud      baud rate (115200)
  --uwb-target    host | asan | serial | qemu (host, or serial when a port is given; the kinds of
                  harness/device/registry.py, which builds the device as the CLI does; `emulator` = host)
  --uwb-firmware  host firmware binary (<repo>/firmware_sim/build/uwb-fw), or the ELF for qemu
  --uwb-qemu-link qemu: usart (default) or semihosting (uwb-fw-semihost.elf, docs/qemu.md)
  --uwb-timeout   seconds to wait for the device (5)

Session options: --uwb-scope session|module|function (how long one device lives, as twister's
--device-testing; default function), --uwb-flash-cmd CMD (or `uwb_flash_cmd` in the ini file: run once
before the first device starts, output in the log, --uwb-flash-timeout).

`uwb_device` yields a started, HELLO-checked device and always stops it. The device identity (firmware
version, build id, model hash, ...) goes to the JUnit report as test-suite properties (xunit2 allows no
properties on a testcase). Marker `hardware`: the test needs a real board and is skipped unless a port
(or --uwb-target serial) is given. `uwb_verdict(summary, max_rmse=..., ...)` judges a run summary with the
checks and thresholds of `uwb-hil run` (harness/report/verdict.py).

Inert unless asked for: this module is imported by every pytest run in the environment (it imports nothing
heavy at the top), but it prints its header, registers and applies the `hardware` marker only when the
session gives a --uwb-* option or its ini file says `uwb_hil = true` (this repository's pyproject.toml
does). Its fixtures work in any session for a test that requests them.
"""

from __future__ import annotations

from pathlib import Path
from contextlib import ExitStack
from typing import TYPE_CHECKING, Any, Iterator, List, Optional, Set, Tuple

import pytest

from harness.device.registry import (QEMU_LINKS, TARGET_CHOICES, TARGETS, DeviceSpec, canonical_target,
                                     create_device, default_firmware, started)
from harness.errors import UsageError, UwbHilError
from harness.options import DEFAULT_BAUD, DEVICE_TIMEOUT_S
from harness.paths import DEFAULT_ASAN_FIRMWARE, DEFAULT_FIRMWARE, DEFAULT_STM32_ELF

if TYPE_CHECKING:
    from harness.device.base import Device
    from harness.device.board_list import BoardSpec

SCOPES = ("session", "module", "function")
DEFAULT_FLASH_TIMEOUT_S = 600.0
_PORT_KEY = pytest.StashKey[Optional[str]]()
_SUITE_PROPS_KEY = pytest.StashKey[Set[Tuple[str, str]]]()
_ACTIVE_KEY = pytest.StashKey[bool]()
_BOARDS_KEY = pytest.StashKey[List["BoardSpec"]]()
_LEASE_KEY = pytest.StashKey[ExitStack]()


# --------------------------------------------------------------------------------------- options
def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("uwb-hil", "uwb-hil device under test")
    group.addoption("--uwb-port", default=None,
                    help="pyserial URL or device path of a real board; when given, tests run against it "
                         "(default: $UWB_HIL_PORT)")
    group.addoption("--uwb-port-serial", default=None, metavar="SERIAL",
                    help="the board whose USB serial number is SERIAL (`uwb-hil ports` lists them)")
    group.addoption("--uwb-baud", type=int, default=None, help=f"baud rate of --uwb-port (default {DEFAULT_BAUD})")
    group.addoption("--uwb-target", choices=TARGET_CHOICES, default=None,
                    help="device kind (default: host, or serial when --uwb-port is given; 'emulator' is host's "
                         "old name)")
    group.addoption("--uwb-firmware", default=None,
                    help=f"firmware: host binary for host (default {DEFAULT_FIRMWARE}), ELF for qemu "
                         f"(default {DEFAULT_STM32_ELF}); asan: {DEFAULT_ASAN_FIRMWARE}")
    group.addoption("--uwb-qemu-link", choices=tuple(QEMU_LINKS), default=None,
                    help="qemu: the guest's link, the emulated USART (default) or semihosting (uwb-fw-semihost.elf, "
                         "whole blocks per trap: the fastest replays; docs/qemu.md)")
    group.addoption("--uwb-timeout", type=float, default=None,
                    help=f"seconds to wait for the device (default {DEVICE_TIMEOUT_S:g})")
    group.addoption("--uwb-scope", choices=SCOPES, default=None,
                    help="lifetime of one device: session, module or function (default; ini uwb_scope)")
    group.addoption("--uwb-flash-cmd", default=None, metavar="CMD",
                    help="shell command run once before the first device starts, e.g. to flash the board "
                         "(ini uwb_flash_cmd); its output goes to the log")
    group.addoption("--uwb-flash-timeout", type=float, default=None,
                    help=f"seconds the flash command may take (default {DEFAULT_FLASH_TIMEOUT_S:g})")
    group.addoption("--uwb-hardware-map", default=None, metavar="FILE",
                    help="board list (YAML: name, port or serial_number, target, baud per board): the device "
                         "tests run once per board, the board's name in the test id and its identity in JUnit")
    group.addoption("--uwb-labgrid-place", default=None, metavar="NAME",
                    help="acquire this labgrid place for the session and test its serial port (RFC 2217); "
                         "released at the end, also on errors and Ctrl-C ([farm] extra)")
    group.addoption("--uwb-labgrid-coordinator", default=None, metavar="HOST:PORT",
                    help="labgrid coordinator (default $LG_COORDINATOR, else 127.0.0.1:20408)")
    parser.addini("uwb_hil", "activate the uwb-hil plugin (report header, `hardware` marker) without a --uwb-* "
                  "option", type="bool", default=False)
    parser.addini("uwb_scope", "default of --uwb-scope", default="function")
    parser.addini("uwb_flash_cmd", "default of --uwb-flash-cmd", default="")


def plugin_active(config: pytest.Config) -> bool:
    """Whether this session asked for uwb-hil: a --uwb-* option given, or `uwb_hil = true` in the ini file.
    Otherwise the plugin is inert (no header, no marker, no skipping): installed in an environment, it
    must not change unrelated projects' sessions. Its fixtures still work for a test that requests them."""
    if config.getini("uwb_hil"):
        return True
    return any(value is not None for name, value in vars(config.option).items() if name.startswith("uwb_"))


def pytest_configure(config: pytest.Config) -> None:
    config.stash[_ACTIVE_KEY] = plugin_active(config)
    if config.stash[_ACTIVE_KEY]:
        config.addinivalue_line("markers", "hardware: needs a real board (--uwb-port or --uwb-target serial)")
        config.addinivalue_line("markers", "uwb_device: uses the device under test (set on every test that "
                                           "requests the uwb_device fixture; `-m uwb_device` selects them)")
    scope = config.getoption("uwb_scope") or config.getini("uwb_scope")
    if scope not in SCOPES:
        raise pytest.UsageError(f"uwb_scope must be one of {SCOPES}, got {scope!r}")
    config.stash[_PORT_KEY] = _configured_port(config)
    config.stash[_SUITE_PROPS_KEY] = set()
    config.stash[_BOARDS_KEY] = _hardware_map(config)
    place = config.getoption("uwb_labgrid_place")
    if place:                     # held for the session: released in pytest_unconfigure (also after Ctrl-C)
        from harness.device.labgrid import PlaceOptions
        from harness.device.labgrid import place as labgrid_place
        stack = ExitStack()
        try:
            lease = stack.enter_context(labgrid_place(PlaceOptions(place, config.getoption("uwb_labgrid_coordinator"))))
        except UwbHilError as exc:
            raise pytest.UsageError(str(exc)) from None
        config.stash[_LEASE_KEY] = stack
        config.stash[_PORT_KEY] = lease.url


def pytest_unconfigure(config: pytest.Config) -> None:
    stack = config.stash.get(_LEASE_KEY, None)
    if stack is not None:
        stack.close()


def _hardware_map(config: pytest.Config) -> list[BoardSpec]:
    path = config.getoption("uwb_hardware_map")
    if not path:
        return []
    from harness.device.board_list import load_board_list
    try:
        return load_board_list(Path(path))
    except UwbHilError as exc:
        raise pytest.UsageError(f"--uwb-hardware-map: {exc}") from None


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """--uwb-hardware-map: every test that uses a device runs once per board (its name in the test id)."""
    boards = metafunc.config.stash.get(_BOARDS_KEY, [])
    names = ("uwb_target", "uwb_port", "uwb_baud", "uwb_firmware")
    if not boards or "uwb_device" not in metafunc.fixturenames:
        return
    taken = {n for m in metafunc.definition.iter_markers("parametrize") for n in _argnames(m)}
    if taken & set(names):
        return                        # the test chose its own device values
    metafunc.parametrize(names, [b.fixture_values() for b in boards], ids=[b.name for b in boards], indirect=True,
                         scope=_device_scope("uwb_device", metafunc.config))  # type: ignore[arg-type]


def _argnames(mark: pytest.Mark) -> list[str]:
    names = mark.args[0] if mark.args else mark.kwargs.get("argnames", "")
    return [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)


def _configured_port(config: pytest.Config) -> str | None:
    """--uwb-port, else the board of --uwb-port-serial, else $UWB_HIL_PORT (unless another target is asked)."""
    from harness.link.ports import PortError, default_port, port_for_serial
    port, serial = config.getoption("uwb_port"), config.getoption("uwb_port_serial")
    if port and serial:
        raise pytest.UsageError("give --uwb-port or --uwb-port-serial, not both")
    if serial:
        try:
            return port_for_serial(serial)
        except PortError as exc:
            raise pytest.UsageError(str(exc)) from None
    if port is None and config.getoption("uwb_target") in (None, "serial"):
        return default_port()
    return str(port) if port is not None else None


def _device_scope(fixture_name: str, config: pytest.Config) -> str:  # noqa: ARG001 - pytest's signature
    """Scope of the device fixtures, chosen at run time (twister-style): --uwb-scope, else the ini value."""
    return str(config.getoption("uwb_scope") or config.getini("uwb_scope"))


def _hardware_selected(config: pytest.Config) -> bool:
    return (bool(config.stash.get(_PORT_KEY, None)) or config.getoption("uwb_target") == "serial"
            or any(b.target == "serial" for b in config.stash.get(_BOARDS_KEY, [])))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not config.stash.get(_ACTIVE_KEY, False):
        return
    for item in items:
        if "uwb_device" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.uwb_device)
    if _hardware_selected(config):
        return
    skip = pytest.mark.skip(reason="needs a real board: give --uwb-port (or --uwb-target serial)")
    for item in items:
        if item.get_closest_marker("hardware") is not None:
            item.add_marker(skip)


def pytest_report_header(config: pytest.Config) -> str | None:
    if not config.stash.get(_ACTIVE_KEY, False):
        return None
    boards = config.stash.get(_BOARDS_KEY, [])
    if boards:
        return (f"uwb-hil: {len(boards)} boards (--uwb-hardware-map): "
                + ", ".join(f"{b.name} {b.target}{' ' + b.port if b.port else ''}" for b in boards))
    port = config.stash.get(_PORT_KEY, None)
    target = canonical_target(config.getoption("uwb_target") or ("serial" if port else "host"))
    if target == "serial":
        return f"uwb-hil: target serial, port {port}, baud {config.getoption('uwb_baud') or DEFAULT_BAUD}"
    fw = Path(config.getoption("uwb_firmware") or default_firmware(target))
    return f"uwb-hil: target {target}, firmware {fw}{'' if fw.exists() else ' (not built)'}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[Any]:
    """A failing test that used `uwb_device` gets the device's link and log and the log's tail in its report."""
    outcome: Any = yield
    report: pytest.TestReport = outcome.get_result()
    device = getattr(item, "funcargs", {}).get("uwb_device")
    if device is None or not report.failed or call.when != "call":
        return
    try:
        link = device.link.name
    except Exception:  # noqa: BLE001 - a stopped device has no link; the report still gets the rest
        link = "-"
    report.sections.append(("uwb device", f"{device.name}, link {link}, log {getattr(device, 'log_path', None)}"))
    tail = getattr(device, "log_tail", None)
    text = tail() if callable(tail) else ""
    if text:
        report.sections.append(("uwb device log (tail)", text))


# ------------------------------------------------------------------------------ option fixtures
# All of them share the device's scope (--uwb-scope): a longer-lived device cannot use shorter-lived values.
def _param_or_option(request: pytest.FixtureRequest, option: str, default: Any) -> Any:
    """Indirect parametrization wins, then the command line, then the default."""
    if hasattr(request, "param"):
        return request.param
    value = request.config.getoption(option)
    return default if value is None else value


@pytest.fixture(scope=_device_scope)
def uwb_port(request: pytest.FixtureRequest) -> str | None:
    if hasattr(request, "param"):
        return None if request.param is None else str(request.param)
    return request.config.stash.get(_PORT_KEY, None)


@pytest.fixture(scope=_device_scope)
def uwb_baud(request: pytest.FixtureRequest) -> int:
    return int(_param_or_option(request, "uwb_baud", DEFAULT_BAUD))


@pytest.fixture(scope=_device_scope)
def uwb_target(request: pytest.FixtureRequest, uwb_port: str | None) -> str:
    target = canonical_target(str(_param_or_option(request, "uwb_target", "serial" if uwb_port else "host")))
    if target not in TARGETS:
        raise pytest.UsageError(f"uwb_target must be one of {TARGETS}, got {target!r}")
    return target


@pytest.fixture(scope=_device_scope)
def uwb_firmware(request: pytest.FixtureRequest, uwb_target: str) -> Path:
    link = str(request.config.getoption("uwb_qemu_link") or "usart")
    return Path(_param_or_option(request, "uwb_firmware", default_firmware(uwb_target, link)))


@pytest.fixture(scope=_device_scope)
def uwb_timeout(request: pytest.FixtureRequest) -> float:
    return float(_param_or_option(request, "uwb_timeout", DEVICE_TIMEOUT_S))


@pytest.fixture(scope=_device_scope)
def uwb_expected_model_hash(request: pytest.FixtureRequest) -> int | None:
    """Model hash the device must report; None = do not check. Override in a conftest or by param."""
    return getattr(request, "param", None)


# ------------------------------------------------------------------------------- device fixture
def _make_device(spec: DeviceSpec) -> Device:
    """The device of the registry (the CLI's construction path); a bad choice fails the test, no traceback."""
    try:
        return create_device(spec)
    except (UsageError, FileNotFoundError) as exc:
        pytest.fail(f"{exc} (pytest options: --uwb-target, --uwb-port, --uwb-firmware)", pytrace=False)


@pytest.fixture(scope="session")
def uwb_flashed(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> str | None:
    """Runs the flash hook (--uwb-flash-cmd / ini uwb_flash_cmd) once, before the first device starts; the
    command, or None when there is none. Its output is logged (logger uwb_hil.flash) and kept in flash.log."""
    cmd = request.config.getoption("uwb_flash_cmd") or request.config.getini("uwb_flash_cmd")
    if not cmd:
        return None
    from harness.device.flash import FlashError, run_flash_command
    timeout = request.config.getoption("uwb_flash_timeout") or DEFAULT_FLASH_TIMEOUT_S
    log_path = tmp_path_factory.mktemp("uwb-flash") / "flash.log"
    try:
        run_flash_command(str(cmd), float(timeout), log_path)
    except FlashError as exc:
        pytest.fail(f"{exc} (log: {log_path})", pytrace=False)
    return str(cmd)


@pytest.fixture(scope=_device_scope)
def uwb_device(request: pytest.FixtureRequest, uwb_target: str, uwb_port: str | None, uwb_baud: int,
               uwb_firmware: Path, uwb_timeout: float, uwb_expected_model_hash: int | None,
               uwb_flashed: str | None, record_testsuite_property: Any,
               tmp_path_factory: pytest.TempPathFactory) -> Iterator[Device]:
    """A started device whose HELLO was checked (protocol version, optional model hash); its lifetime is
    --uwb-scope (function by default).

    The HELLO (firmware version, build id, model hash as the CLI prints it), the target kind and the
    connection (port, baud, USB serial number when the port has one) become JUnit
    test-suite properties (once per distinct value), which xunit2 accepts; per-device details (link,
    exit code, log) go to the report of a failing test instead of testcase properties, which it rejects.
    """
    recorded = request.config.stash[_SUITE_PROPS_KEY]

    def suite_property(name: str, value: object) -> None:
        if (name, str(value)) not in recorded:
            recorded.add((name, str(value)))
            record_testsuite_property(name, str(value))

    log_dir = tmp_path_factory.mktemp("uwb-device", numbered=True)
    # the flash hook ran once for the session (uwb_flashed), not per device: no flash_cmd here
    spec = DeviceSpec(target=uwb_target, port=uwb_port if uwb_target == "serial" else None, baud=uwb_baud,
                      firmware=uwb_firmware, timeout_s=uwb_timeout, log_dir=log_dir,
                      qemu_link=str(request.config.getoption("uwb_qemu_link") or "usart"))
    device = _make_device(spec)
    suite_property("uwb_target", uwb_target)
    with started(device, uwb_timeout, uwb_expected_model_hash):
        for key, value in device.identity.properties().items():
            suite_property(key, value)
        for key, value in device.connection().items():   # port, baud, usb_serial (when known)
            if value is not None:
                suite_property(f"uwb_{key}", value)
        board = _board_of(request)
        if board is not None:        # --uwb-hardware-map: which board this test ran on, and what it is
            suite_property(f"uwb_board_{board.name}", board.identity_text(device.identity.as_dict()))
        if uwb_flashed:
            suite_property("uwb_flash_cmd", uwb_flashed)
        yield device


def _board_of(request: pytest.FixtureRequest) -> BoardSpec | None:
    """The --uwb-hardware-map board this test item runs on (from its device parameters)."""
    callspec = getattr(getattr(request, "node", None), "callspec", None)
    values = getattr(callspec, "params", {})
    key = tuple(str(values.get(n)) for n in ("uwb_target", "uwb_port", "uwb_baud", "uwb_firmware"))
    same = [b for b in request.config.stash.get(_BOARDS_KEY, []) if tuple(map(str, b.fixture_values())) == key]
    ids = f"-{getattr(callspec, 'id', '')}-"
    return next((b for b in same if f"-{b.name}-" in ids), same[0] if same else None)


# ------------------------------------------------------------------------------------- verdicts
@pytest.fixture
def uwb_verdict() -> Any:
    """`uwb_verdict(summary, max_rmse=0.1, ...)`: the verdict `uwb-hil run` gives a run summary
    (harness.report.metrics.run_summary), with the same health checks and thresholds
    (harness/report/verdict.py); fails the test naming every failed check, returns the Verdict."""
    from harness.report.verdict import assert_verdict
    return assert_verdict
