"""Bench conventions of pytest-embedded / twister / labgrid: the device identity as JUnit test-suite
properties (the file validates against the xunit2 schema), the device fixture's scope chosen at run time,
a flash hook before the session, picking a board by USB serial number or $UWB_HIL_PORT, `uwb-hil ports`."""

from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from harness.cli import main
from harness.link.ports import PortError, PortInfo, port_for_serial, ports_present
from harness.paths import DEFAULT_FIRMWARE, REPO_ROOT

pytest_plugins = ["pytester"]
XSD = REPO_ROOT / "tests" / "fixtures" / "junit-xunit2.xsd"
_LEAN = ("-p", "no:hypothesispytest", "-p", "no:cacheprovider")
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")

DEVICE_TESTS = """
import pytest

def test_passes(uwb_device):
    assert uwb_device.alive()

def test_fails(uwb_device):
    assert False, "estimate diverged"

@pytest.mark.skip(reason="not today")
def test_skipped(uwb_device):
    pass
"""


# --------------------------------------------------------------------------------------- JUnit xunit2
def xunit2_problems(path: Path) -> list[str]:
    """Violations of the xunit2 schema (tests/fixtures/junit-xunit2.xsd): validated with lxml when it is
    installed (the [test] extra), else the structural rules that matter here, checked by hand."""
    try:
        from lxml import etree
    except ImportError:
        etree = None
    if etree is not None:
        schema = etree.XMLSchema(etree.parse(str(XSD)))
        ok = schema.validate(etree.parse(str(path)))
        return [] if ok else [f"line {e.line}: {e.message}" for e in schema.error_log]
    problems = []
    root = ET.parse(path).getroot()
    for case in root.iter("testcase"):
        for child in case:
            if child.tag not in ("skipped", "error", "failure", "system-out", "system-err"):
                problems.append(f"testcase {case.get('name')}: element <{child.tag}> not allowed")
    return problems


def _suite_properties(path: Path) -> list[tuple[str, str]]:
    suite = ET.parse(path).getroot().find("testsuite")
    assert suite is not None
    return [(p.get("name", ""), p.get("value", "")) for p in suite.iterfind("properties/property")]


@needs_fw
def test_junit_xunit2_file_validates_with_the_device_identity_as_suite_properties(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(DEVICE_TESTS)
    xml = pytester.path / "junit.xml"
    result = pytester.runpytest_subprocess(*_LEAN, f"--junitxml={xml}", "-o", "junit_family=xunit2")
    result.assert_outcomes(passed=1, failed=1, skipped=1)
    assert "record_property" not in result.stdout.str()        # no xunit2 warning either
    assert xunit2_problems(xml) == []
    props = _suite_properties(xml)
    names = [n for n, _ in props]
    for name in ("uwb_target", "uwb_fw_version", "uwb_build_id", "uwb_model_hash", "uwb_proto_version"):
        assert names.count(name) == 1, props               # once, although two tests started a device
    # the hash as the CLI prints it (16 hex digits, no 0x); the port of each device (a pty per host device)
    model_hash = dict(props)["uwb_model_hash"]
    assert dict(props)["uwb_target"] == "host" and len(model_hash) == 16 and not model_hash.startswith("0x")
    assert dict(props)["uwb_port"].startswith("/dev/")
    assert ET.parse(xml).getroot().find(".//testcase/properties") is None


def test_the_schema_check_rejects_properties_inside_a_testcase(tmp_path: Path) -> None:
    bad = tmp_path / "old.xml"     # what the plugin wrote before (testcase properties)
    bad.write_text('<testsuites><testsuite name="pytest" tests="1" failures="0" errors="0">'
                   '<testcase classname="t" name="test_a" time="0.1"><properties>'
                   '<property name="uwb_model_hash" value="0x1"/></properties></testcase></testsuite></testsuites>')
    problems = xunit2_problems(bad)
    assert problems and "properties" in problems[0]


def test_the_structural_check_without_lxml_applies_the_same_rule(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "lxml", None)
    case = '<testcase classname="t" name="test_a" time="0.1">{}</testcase>'
    suite = '<testsuites><testsuite name="pytest" tests="1" failures="0" errors="0">{}</testsuite></testsuites>'
    good, bad = tmp_path / "good.xml", tmp_path / "bad.xml"
    good.write_text(suite.format('<properties><property name="uwb_model_hash" value="0x1"/></properties>'
                                 + case.format('<failure message="x">tb</failure><system-out>o</system-out>')))
    bad.write_text(suite.format(case.format('<properties><property name="a" value="b"/></properties>')))
    assert xunit2_problems(good) == []
    assert xunit2_problems(bad) == ["testcase test_a: element <properties> not allowed"]


# --------------------------------------------------------------------------------------- fixture scope
SCOPE_CONFTEST = "SEEN = []\n"
SCOPE_A = """
from conftest import SEEN

def test_a1(uwb_device):
    SEEN.append(uwb_device)

def test_a2(uwb_device):
    SEEN.append(uwb_device)
"""
SCOPE_B = """
from conftest import SEEN

def test_b1(uwb_device):
    SEEN.append(uwb_device)
    distinct = list({id(d): d for d in SEEN}.values())
    print("DEVICES", len(distinct), "ALIVE", sum(d.alive() for d in distinct))   # earlier ones were stopped
"""


@needs_fw
@pytest.mark.parametrize("scope,devices,alive", [("session", 1, 1), ("module", 2, 1), ("function", 3, 1)])
def test_device_scope_is_chosen_at_run_time(pytester: pytest.Pytester, scope: str, devices: int, alive: int) -> None:
    pytester.makeconftest(SCOPE_CONFTEST)
    pytester.makepyfile(test_a=SCOPE_A, test_b=SCOPE_B)
    result = pytester.runpytest(*_LEAN, "-s", "--uwb-scope", scope)
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines([f"*DEVICES {devices} ALIVE {alive}*"])


@needs_fw
def test_device_scope_from_the_ini_file(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(SCOPE_CONFTEST)
    pytester.makeini("[pytest]\nuwb_scope = session\n")
    pytester.makepyfile(test_a=SCOPE_A, test_b=SCOPE_B)
    result = pytester.runpytest(*_LEAN, "-s")
    result.stdout.fnmatch_lines(["*DEVICES 1 ALIVE 1*"])


# ------------------------------------------------------------------------------------------- flash hook
@needs_fw
def test_flash_command_runs_once_before_the_devices_and_is_logged(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(SCOPE_CONFTEST)
    pytester.makepyfile(test_a=SCOPE_A, test_b=SCOPE_B)
    count = pytester.path / "flashed.txt"
    cmd = f"echo flashing board 42; echo x >> {count}"
    xml = pytester.path / "junit.xml"
    result = pytester.runpytest(*_LEAN, "--uwb-flash-cmd", cmd, "--log-cli-level=INFO", f"--junitxml={xml}")
    result.assert_outcomes(passed=3)
    assert count.read_text() == "x\n"                        # once for the session, not per device
    result.stdout.fnmatch_lines(["*flash: running echo flashing board 42*", "*flash: flashing board 42*"])
    assert ("uwb_flash_cmd", cmd) in _suite_properties(xml)


def test_a_failing_flash_command_fails_the_device_tests_with_its_output(pytester: pytest.Pytester) -> None:
    pytester.makeini("[pytest]\nuwb_flash_cmd = echo no probe found >&2; exit 3\n")
    pytester.makepyfile(DEVICE_TESTS)
    result = pytester.runpytest(*_LEAN)
    result.assert_outcomes(errors=2, skipped=1)
    result.stdout.fnmatch_lines(["*flash command 'echo no probe found >&2; exit 3' failed (exit 3)*",
                                 "*no probe found*"])


def test_a_hanging_flash_command_times_out(pytester: pytest.Pytester) -> None:
    pytester.makepyfile("def test_dev(uwb_device):\n    pass\n")
    result = pytester.runpytest(*_LEAN, "--uwb-flash-cmd", "sleep 30", "--uwb-flash-timeout", "0.5")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*flash command 'sleep 30' did not finish within 0.5 s*"])


# ------------------------------------------------------------------------------------------------ ports
PORTS = [PortInfo("/dev/ttyACM0", "Crazyflie 2.1", "206A3358", "USB VID:PID=0483:5740"),
         PortInfo("/dev/ttyACM1", "STM32 Virtual ComPort", "3376395D", "USB VID:PID=0483:5740"),
         PortInfo("/dev/ttyS0", "n/a", None, "n/a")]


def test_a_board_is_picked_by_its_usb_serial_number() -> None:
    assert port_for_serial("3376395D", PORTS) == "/dev/ttyACM1"
    with pytest.raises(PortError, match=r"no serial port has USB serial number 'nope'; ports present: "
                                        r"/dev/ttyACM0 \(Crazyflie 2.1, serial 206A3358\); /dev/ttyACM1"):
        port_for_serial("nope", PORTS)
    with pytest.raises(PortError, match="2 serial ports have"):
        port_for_serial("X", [PORTS[0], PortInfo("/dev/ttyACM9", "clone", "X", ""), PortInfo("/dev/t", "c", "X", "")])
    assert ports_present([]) == "no serial ports found on this machine"


def test_plugin_takes_the_port_from_the_environment_and_by_serial_number(pytester: pytest.Pytester,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    pytester.makepyfile("def test_values(uwb_port, uwb_target):\n    print('VALUES', uwb_port, uwb_target)\n")
    monkeypatch.setenv("UWB_HIL_PORT", "socket://127.0.0.1:9")
    result = pytester.runpytest(*_LEAN, "-s")
    result.stdout.fnmatch_lines(["*VALUES socket://127.0.0.1:9 serial*"])
    result = pytester.runpytest(*_LEAN, "-s", "--uwb-target", "emulator")     # another target: env ignored
    result.stdout.fnmatch_lines(["*VALUES None host*"])                       # (emulator: host's old name)
    monkeypatch.setattr("harness.link.ports.list_ports", lambda: PORTS)
    result = pytester.runpytest(*_LEAN, "-s", "--uwb-port-serial", "206A3358")
    result.stdout.fnmatch_lines(["*VALUES /dev/ttyACM0 serial*"])
    result = pytester.runpytest(*_LEAN, "--uwb-port-serial", "nope")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*no serial port has USB serial number 'nope'; ports present: /dev/ttyACM0*"])


def test_cli_ports_and_port_serial(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("harness.link.ports.list_ports", lambda: PORTS)
    monkeypatch.setenv("UWB_HIL_PORT", "/dev/ttyACM1")
    assert main(["ports"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[0] == "/dev/ttyACM0" and out[0].endswith("serial 206A3358")
    assert out[-1] == "default port ($UWB_HIL_PORT): /dev/ttyACM1"
    assert main(["ports", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["default"] == "/dev/ttyACM1" and doc["ports"][1]["serial_number"] == "3376395D"
    assert main(["run", "--port-serial", "nope", "--duration", "2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: no serial port has USB serial number 'nope'; ports present:")
    assert main(["run", "--port-serial", "206A3358", "--port", "/dev/x", "--duration", "2"]) == 2
    assert "not both" in capsys.readouterr().err


@needs_fw
def test_cli_flash_command_runs_before_the_device_and_a_failure_stops_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "flashed"
    assert main(["run", "--duration", "2", "--log-dir", str(tmp_path), "--flash-cmd",
                 f"echo flashing board 7; touch {marker}"]) == 0
    err = capsys.readouterr().err
    assert marker.exists() and "uwb-hil: flash: flashing board 7" in err
    assert "flashing board 7" in (tmp_path / "flash.log").read_text()
    code = main(["run", "--duration", "2", "--flash-cmd", "echo no probe >&2; exit 4"])
    err = capsys.readouterr().err
    assert code != 0 and "uwb-hil: error: flash command 'echo no probe >&2; exit 4' failed (exit 4)" in err
