"""The uwb-hil pytest plugin (harness/pytest_plugin.py): inert unless a project asks for it, its options and
their fixtures, and the `uwb_device` fixture on the stand-in firmware and a socket:// board (stand_ins.py)."""

from __future__ import annotations

from pathlib import Path

import numpy  # noqa: F401  (pytester's in-process runs drop the modules first imported inside them, and
import pytest  # numpy's C core cannot be imported twice in one process: import it here, before any inner run)

from stand_ins import FAKE_HASH, FakeBoard, board, fake_fw, write_script  # noqa: F401

pytestmark = pytest.mark.timeout(60)
pytest_plugins = ["pytester"]
# Inner runs re-import every plugin; hypothesis alone takes a second and is not needed there.
_LEAN = ("-p", "no:hypothesispytest", "-p", "no:cacheprovider")


def _run(pytester: pytest.Pytester, *args: str) -> pytest.RunResult:
    return pytester.runpytest(*_LEAN, *args)

OPTION_PROBE = """
import pytest

def test_values(uwb_port, uwb_baud, uwb_target, uwb_firmware, uwb_timeout):
    print("VALUES", uwb_port, uwb_baud, uwb_target, uwb_firmware.name, uwb_timeout)

@pytest.mark.parametrize("uwb_baud", [921600], indirect=True)
@pytest.mark.parametrize("uwb_port", ["socket://127.0.0.1:9"], indirect=True)
def test_indirect(uwb_port, uwb_baud, uwb_target):
    print("INDIRECT", uwb_port, uwb_baud, uwb_target)

@pytest.mark.hardware
def test_board_only():
    print("HARDWARE RAN")
"""


def test_plugin_is_inert_in_a_project_that_does_not_ask_for_it(pytester: pytest.Pytester) -> None:
    """Installed in an environment, the plugin loads in every pytest session: without a --uwb-* option or
    `uwb_hil = true` in the ini, no header, and a project's own `hardware` marker is left alone."""
    pytester.makeini("[pytest]\nmarkers =\n    hardware: this project's own marker\n")
    pytester.makepyfile("import pytest\n\n@pytest.mark.hardware\ndef test_mine():\n    pass\n")
    result = _run(pytester)
    result.assert_outcomes(passed=1)
    assert "uwb-hil:" not in result.stdout.str()          # (pytest itself lists "plugins: uwb-hil-...")
    asked = _run(pytester, "--uwb-timeout", "2")             # any --uwb-* option asks for it
    asked.assert_outcomes(skipped=1)
    asked.stdout.fnmatch_lines(["uwb-hil: target host, *"])


def test_plugin_options_are_in_their_own_help_group(pytester: pytest.Pytester) -> None:
    result = _run(pytester, "--help")
    result.stdout.fnmatch_lines(["*uwb-hil*", "*--uwb-port*", "*--uwb-baud*", "*--uwb-target*",
                                 "*--uwb-firmware*", "*--uwb-timeout*"])


def test_plugin_option_fixtures_defaults_cli_and_indirect(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(OPTION_PROBE)
    pytester.makeini("[pytest]\nuwb_hil = true\n")     # a project that asks for the plugin without options
    result = _run(pytester, "-s", "-rs")
    result.assert_outcomes(passed=2, skipped=1)
    result.stdout.fnmatch_lines(["*VALUES None 115200 host uwb-fw 5.0",
                                 "*INDIRECT socket://127.0.0.1:9 921600 serial",
                                 "*needs a real board*"])
    result = _run(pytester, "-s", "--uwb-port", "loop://", "--uwb-baud", "9600", "--uwb-timeout", "2",
                                "--uwb-firmware", "/x/fw")
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines(["*VALUES loop:// 9600 serial fw 2.0", "*HARDWARE RAN"])
    result = _run(pytester, "-s", "--uwb-target", "qemu", "-k", "values")      # qemu: the STM32 ELF by default
    result.stdout.fnmatch_lines(["*VALUES None 115200 qemu uwb-fw.elf 5.0"])


def test_plugin_uwb_device_records_hello(pytester: pytest.Pytester, fake_fw: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            assert uwb_device.alive()
            assert uwb_device.last_hello.fw_minor == 2
            print("DEVICE", uwb_device.link.name)
    """)
    xml = pytester.path / "junit.xml"
    result = _run(pytester, "-s", "--uwb-firmware", str(fake_fw), f"--junitxml={xml}")
    result.assert_outcomes(passed=1, warnings=0)
    result.stdout.fnmatch_lines(["uwb-hil: target host, firmware *fake-fw", "*DEVICE pty:/dev/*"])
    text = xml.read_text()
    for expected in ('name="uwb_fw_version" value="1.2.3"', 'name="uwb_build_id" value="fake-id"',
                     f'name="uwb_model_hash" value="{FAKE_HASH:016x}"', 'name="uwb_device_target" value="fake"',
                     'name="uwb_target" value="host"', 'name="uwb_port" value="/dev/'):
        assert expected in text
    # test-suite properties (xunit2 rejects them inside a testcase)
    assert text.index("<properties>") < text.index("<testcase") and "</properties></testcase>" not in text


def test_plugin_failing_test_shows_the_device_log(pytester: pytest.Pytester, fake_fw: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            assert False, "estimate diverged"
    """)
    result = _run(pytester, "--uwb-firmware", str(fake_fw))
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*uwb device log (tail)*", "*fake firmware serving /dev/pts/*"])


def test_plugin_uwb_device_checks_the_protocol_and_always_stops(pytester: pytest.Pytester, fake_fw: Path) -> None:
    wrapper = write_script(pytester.path, "fw-proto-99", f"#!/bin/sh\nexec {fake_fw} \"$@\" --proto 99\n")
    pytester.makepyfile("""
        def test_dev(uwb_device):
            pass
    """)
    result = _run(pytester, "--uwb-firmware", str(wrapper))
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*ProtocolMismatch*reports 99*"])


def test_plugin_uwb_device_on_a_serial_url(pytester: pytest.Pytester, board: FakeBoard) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device, uwb_target):
            assert uwb_target == "serial"
            assert uwb_device.last_hello.target.rstrip(b"\\0") == b"stm32"
    """)
    result = _run(pytester, "--uwb-port", board.url)
    result.assert_outcomes(passed=1)


def test_plugin_missing_firmware_is_a_clear_error(pytester: pytest.Pytester, tmp_path: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            pass
    """)
    result = _run(pytester, "--uwb-firmware", str(tmp_path / "nope"))
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*firmware binary*nope not found*make firmware*"])

