"""Campaign options are refused before any worker starts (exit 2, the option named), not by every run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from harness.cli import main


@pytest.mark.parametrize("argv,match", [
    (["--duration", "10"], r"--duration 10: simulated flights need more than 10.5 s"),
    (["--duration", "nan"], r"--duration nan"),
    (["--trajectories", "circle,loop"], r"unknown trajectory 'loop'"),
    (["--jobs", "0"], r"--jobs must be >= 1"),
    (["--timeout", "-1"], r"--timeout must be in"),
    (["--firmware", "/nonexistent/uwb-fw"], r"firmware binary /nonexistent/uwb-fw not found"),
    (["--sim-model", "/nonexistent/m.npz"], r"--sim-model /nonexistent/m.npz: file not found"),
])
def test_bad_campaign_options_are_refused_before_any_worker(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                           argv: list[str], match: str) -> None:
    out = tmp_path / "c"
    code = main(["campaign", "--out", str(out), "--seeds", "1", "--no-recorded", *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("uwb-hil: error: ") and len(err.strip().splitlines()) == 1
    assert re.search(match, err), err
    assert not out.exists()          # nothing planned, nothing started


def test_run_on_qemu_refuses_a_missing_firmware(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--target", "qemu", "--firmware", "/nonexistent.elf", "--duration", "2"])
    err = capsys.readouterr().err
    assert code == 2
    assert "uwb-hil: error: firmware ELF /nonexistent.elf not found" in err
