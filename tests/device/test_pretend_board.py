"""A board that stays plugged in: one host-firmware process on a pty for many runs and test sessions
(harness/device/pretend_board.py, what `make test-board` runs tests/device against), the device named in
every run's text output and in JUnit (port, baud, USB serial number, model hash in the CLI's form).

The `hardware` tests run only with --uwb-port (a real board, or the pretend board in CI)."""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import asdict

import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.device.board_process import PtyBoard
from harness.device.pretend_board import main as pretend_main, pretend_board
from harness.flight.run_config import config_for
from harness.flight.scenarios import scenario_flight
from harness.link.ports import PortInfo, serial_number_of
from harness.paths import DEFAULT_FIRMWARE
from harness.stream.streamer import Pacing, Streamer

pytest_plugins = ["pytester"]
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")
DEVICE_LINE = re.compile(r"^device: target host, port (/dev/\S+), build \S+, model [0-9a-f]{16}, stages outlier$")


@pytest.fixture
def board() -> Iterator[PtyBoard]:
    with pretend_board() as b:
        yield b


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "harness.cli", *args], capture_output=True, text=True, timeout=300)


@needs_fw
def test_two_runs_on_one_board_name_the_device_and_pass(board: PtyBoard) -> None:
    for _ in range(2):      # the board is not restarted between runs
        r = _cli("run", "--port", board.port, "--duration", "4", "--stages", "outlier")
        assert r.returncode == 0, r.stderr
        first = r.stdout.splitlines()[0]
        m = DEVICE_LINE.match(first)
        assert m and m.group(1) == board.port, first
    assert board.alive()


@needs_fw
def test_junit_names_port_baud_and_hash_without_0x(board: PtyBoard, pytester: pytest.Pytester) -> None:
    pytester.makepyfile("def test_dev(uwb_device):\n    assert uwb_device.alive()\n")
    xml = pytester.path / "junit.xml"
    result = pytester.runpytest("-p", "no:cacheprovider", "--uwb-port", board.port, f"--junitxml={xml}")
    result.assert_outcomes(passed=1)
    text = xml.read_text()
    assert f'name="uwb_port" value="{board.port}"' in text and 'name="uwb_baud" value="115200"' in text
    assert re.search(r'name="uwb_model_hash" value="[0-9a-f]{16}"', text), text


def test_usb_serial_number_of_a_port_by_its_path() -> None:
    ports = [PortInfo("/dev/ttyACM0", "Crazyflie", "206A3358", "USB"), PortInfo("/dev/ttyS0", "n/a", None, "")]
    assert serial_number_of("/dev/ttyACM0", ports) == "206A3358"
    assert serial_number_of("/dev/ttyS0", ports) is None
    assert serial_number_of("rfc2217://host:2000", ports) is None


@needs_fw
def test_wrapper_runs_a_command_against_one_board_and_returns_its_code(capfd: pytest.CaptureFixture[str]) -> None:
    code = pretend_main(["--", sys.executable, "-c", "import os, sys; sys.exit(0 if os.path.exists('{port}') else 5)"])
    assert code == 0
    assert pretend_main(["--", sys.executable, "-c", "raise SystemExit(7)"]) == 7
    assert "pretend board:" in capfd.readouterr().err


def test_wrapper_without_a_command_or_firmware_is_a_usage_error(tmp_path, capsys) -> None:  # noqa: ANN001
    with pytest.raises(SystemExit) as exc:
        pretend_main([])
    assert exc.value.code == 2
    assert pretend_main(["--firmware", str(tmp_path / "none"), "--", "true"]) == 2
    assert "not found" in capsys.readouterr().err


@pytest.mark.hardware
def test_board_counters_only_grow_between_runs(uwb_device) -> None:  # noqa: ANN001
    """A board on the bench keeps counting: tests compare deltas (STATS before and after), never totals."""
    flight = scenario_flight("circle", mode="twr", duration_s=3.0, seed=4)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    streamer = Streamer(uwb_device)
    first = streamer.run(flight, cfg, Pacing("windowed", 64))
    second = streamer.run(flight, cfg, Pacing("windowed", 64))
    assert first.stats is not None and second.stats_start is not None and second.stats is not None
    a, b0, b1 = asdict(first.stats), asdict(second.stats_start), asdict(second.stats)
    assert b0["frames_ok"] >= a["frames_ok"]
    # each run's delta is its own flight, whatever ran before
    assert b1["frames_ok"] - b0["frames_ok"] >= len(flight.uwb)
