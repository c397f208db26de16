"""Inputs can't hurt (issue 27): an output path that is an input of the run, pacing speed, ... Every case
asserts the exit code, the one-line message and that the input file is intact."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from harness import cli

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "tests" / "fixtures" / "recordings"
REDUCED = FIX / "const1-fixture-tdoa2.csv"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("how", ["same path", "hard link", "anchors"])
def test_results_over_an_input_is_refused_even_with_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              how: str) -> None:
    rec, anchors = tmp_path / "rec.csv", tmp_path / "anchors.csv"
    shutil.copy(REDUCED, rec)
    shutil.copy(FIX / "anchors.csv", anchors)
    target = {"same path": rec, "anchors": anchors, "hard link": tmp_path / "link.jsonl"}[how]
    if how == "hard link":
        os.link(rec, target)
    before = {p: _digest(p) for p in (rec, anchors)}
    code = cli.main(["run", "--recording", str(rec), "--anchors", str(anchors), "--results", str(target), "--overwrite"])
    assert code == 2
    err = _one_error(capsys)
    assert err.startswith(f"uwb-hil: error: results file {target} is an input of this run"), err
    assert {p: _digest(p) for p in (rec, anchors)} == before


def test_results_inside_a_recording_folder_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = tmp_path / "sequence9"
    seq.mkdir()
    victim = seq / "uwb_range.csv"
    victim.write_text("t,range\n")
    assert cli.main(["run", "--recording", str(seq), "--results", str(victim), "--overwrite"]) == 2
    assert "is an input of this run" in _one_error(capsys) and victim.read_text() == "t,range\n"
