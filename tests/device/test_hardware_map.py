"""Several boards in one pytest session (`--uwb-hardware-map FILE`, harness/pytest_plugin.py): every test that
uses `uwb_device` runs once per board of the list, the board's name in the test id and its identity (target,
port, HELLO build and model) in the JUnit report; a test that chooses its own device values is left alone."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.paths import DEFAULT_FIRMWARE

pytest_plugins = ["pytester"]
pytestmark = [pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)"),
              pytest.mark.timeout(120)]
_LEAN = ("-p", "no:hypothesispytest", "-p", "no:cacheprovider")

PROBE = """
import pytest

def test_dev(uwb_device, uwb_target):
    print("RAN", uwb_target, uwb_device.identity.build_id)

@pytest.mark.parametrize("uwb_target", ["host"], indirect=True)
def test_own_choice(uwb_device):
    pass

def test_no_device():
    pass
"""


def test_device_tests_run_once_per_board(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(PROBE)
    boards = pytester.path / "boards.yaml"
    boards.write_text(f"- {{name: hostA, target: host}}\n- {{name: hostB, target: asan}}\n")
    xml = pytester.path / "junit.xml"
    result = pytester.runpytest(*_LEAN, "-s", "-v", "--uwb-hardware-map", str(boards), f"--junitxml={xml}")
    result.assert_outcomes(passed=4)
    result.stdout.fnmatch_lines(["uwb-hil: 2 boards (--uwb-hardware-map): hostA host, hostB asan",
                                 "*test_dev?hostA? RAN host *", "*test_dev?hostB? RAN asan *"])
    text = xml.read_text()
    assert 'name="test_dev[hostA]"' in text and 'name="test_dev[hostB]"' in text
    for name, target in (("hostA", "host"), ("hostB", "asan")):
        assert f'name="uwb_board_{name}" value="{target} {target} build ' in text


def test_a_bad_hardware_map_is_a_usage_error(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(PROBE)
    bad = pytester.path / "boards.yaml"
    bad.write_text("- {name: a, target: serial}\n")
    result = pytester.runpytest(*_LEAN, "--uwb-hardware-map", str(bad))
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*--uwb-hardware-map*needs a port or a serial_number*"])
