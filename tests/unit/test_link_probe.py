"""scripts/link_probe.py: link inputs, the decision rule fixed before trial 5, and its refusals."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Callable

import numpy as np
import pytest


@pytest.fixture(scope="module")
def lp(script_module: Callable[[str], ModuleType]) -> ModuleType:
    return script_module("link_probe")


def test_link_inputs_split_the_pair_and_add_the_range(lp: ModuleType) -> None:
    x = np.array([[3.0, 0.0, 4.0, 0.0, 1.0, 0.0]])
    a, b = lp.link_inputs(x, "dp")
    assert a.tolist() == [[3.0, 0.0, 4.0]] and b.tolist() == [[0.0, 1.0, 0.0]]
    a, b = lp.link_inputs(x, "dpn")
    assert a[0, 3] == pytest.approx(5.0) and b[0, 3] == pytest.approx(1.0)


def _rows(gains: list[float]) -> list[dict[str, object]]:
    """12 left-out sets; link-x beats A by gains[i] points on set i; A beats voxel by 2."""
    rows: list[dict[str, object]] = []
    for i, g in enumerate(gains):
        methods = {"voxel": {"cut": 28.0, "share": 70.0}, "A": {"cut": 30.0, "share": 75.0},
                   "link-x": {"cut": 30.0 + g, "share": 75.0}, "link-x-single": {"cut": 40.0, "share": 90.0}}
        rows.append({"seed": 0, "trial": 1 + i // 3, "set": f"s{i % 3}", "methods": methods})
    return rows


def test_decision_rule_mean_gain_and_sets_worse(lp: ModuleType) -> None:
    methods = ["voxel", "A", "link-x", "link-x-single"]
    s = lp.summary(_rows([2.0] * 9 + [-0.5] * 3), methods)["methods"]
    assert s["link-x"]["gain_over_A"] == pytest.approx((18.0 - 1.5) / 12)
    assert s["link-x"]["sets_worse_than_A"] == 3 and s["link-x"]["adopt"]
    assert s["A"]["gain_over_voxel"] == pytest.approx(2.0) and not s["A"]["adopt"]
    assert not s["link-x-single"]["adopt"]          # single networks are reported, never adopted
    s = lp.summary(_rows([2.0] * 8 + [-0.5] * 4), methods)["methods"]
    assert not s["link-x"]["adopt"]                 # worse than A on 4 sets
    s = lp.summary(_rows([0.9] * 12), methods)["methods"]
    assert not s["link-x"]["adopt"]                 # mean gain below +1 point


def test_trial_5_and_missing_inputs_are_refused(lp: ModuleType, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["link_probe.py", "--data", str(tmp_path), "--trials", "5"])
    with pytest.raises(SystemExit) as e:
        lp.main()
    assert e.value.code == 2
    monkeypatch.setattr(sys, "argv", ["link_probe.py", "--data", str(tmp_path)])
    assert lp.main() == 2                           # no recordings
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    monkeypatch.setattr(sys, "argv", ["link_probe.py", "--rows-from", str(bad)])
    assert lp.main() == 2


def test_rows_from_prints_the_table_without_the_data(lp: ModuleType, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "s0.json"
    f.write_text(json.dumps({"rows": _rows([2.0] * 12)}))
    monkeypatch.setattr(sys, "argv", ["link_probe.py", "--data", str(tmp_path / "none"), "--rows-from", str(f)])
    assert lp.main() == 0
    out = capsys.readouterr().out
    assert "| link-x | 32.00 |" in out and "| yes |" in out
