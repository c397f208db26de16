"""`uwb-hil models` and firmware_sim/models/models.json: a network trained on the shared recordings that is
skipped because they are not there keeps its committed entry (it used to be overwritten by a "skipped" one,
exit 0), and the skip is named on stderr. Nothing is trained: the data folder is an empty directory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from harness import cli
from harness.biasnet import shipped
from harness.biasnet.registry import SUMMARY


@pytest.fixture
def summary_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A copy of the committed models.json that shipped.py writes to instead (and its models folder)."""
    copy = tmp_path / "models" / "models.json"
    copy.parent.mkdir()
    copy.write_text(SUMMARY.read_text())
    monkeypatch.setattr(shipped, "SUMMARY", copy)
    monkeypatch.setattr(shipped, "MODELS_DIR", copy.parent)
    return copy


@pytest.mark.parametrize("only, name", [("util", "util_tdoa_pos"), ("rcv", "rcv_twr"), ("cfusd", "cf_tdoa_pose")])
def test_a_model_skipped_for_missing_data_keeps_its_committed_entry(only: str, name: str, summary_copy: Path,
                                                                     tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "no-data"
    empty.mkdir()
    before = summary_copy.read_text()
    committed = json.loads(before)[name]
    assert "skipped" not in committed and "heldout" in committed
    assert cli.main(["models", "--only", only, "--data", str(empty)]) == 0
    assert summary_copy.read_text() == before                  # untouched: nothing was built
    err = capsys.readouterr().err
    assert f"{name} not built" in err and str(empty) in err and "models.json keeps its entry" in err


def test_the_merge_writes_what_was_built_and_keeps_the_skipped_ones_entries(summary_copy: Path) -> None:
    old = json.loads(summary_copy.read_text())
    built = {"file": "firmware_sim/models/rcv_twr.npz", "hash": "0123456789abcdef", "heldout": {}}
    shipped._merge_summary({"command": "make models", "machine": "test", "python": "3",
                            "rcv_twr": built, "util_tdoa_pos": {"skipped": "the shared recordings are not there"}})
    new = json.loads(summary_copy.read_text())
    assert new["rcv_twr"] == built and new["machine"] == "test"
    assert new["util_tdoa_pos"] == old["util_tdoa_pos"]        # the committed entry, not a "skipped" one
    assert {k: v for k, v in new.items() if k not in ("rcv_twr", "machine", "python", "command")} == \
        {k: v for k, v in old.items() if k not in ("rcv_twr", "machine", "python", "command")}
