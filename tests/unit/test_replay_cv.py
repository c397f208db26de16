"""scripts/replay_cv.py: the grid, the out-of-fold flights (never trial 5) and its refusal without folds."""

from __future__ import annotations

import sys
from pathlib import Path
from types import ModuleType
from typing import Callable

import pytest


@pytest.fixture(scope="module")
def rcv(script_module: Callable[[str], ModuleType]) -> ModuleType:
    return script_module("replay_cv")


def test_grid_is_the_cartesian_product(rcv: ModuleType) -> None:
    grid = rcv.parse_grid(["proc_cv_acc=1,2", "std_tdoa=0.1,0.2,0.3"])
    assert len(grid) == 6
    assert {"proc_cv_acc": "2", "std_tdoa": "0.3"} in grid
    assert rcv.parse_grid([]) == [{}]
    with pytest.raises(SystemExit):
        rcv.parse_grid(["proc_cv_acc"])


def test_training_flights_are_trials_1_to_4_with_their_mode(rcv: ModuleType, tmp_path: Path) -> None:
    for c, modes in ((1, ("tdoa2", "tdoa3")), (2, ("tdoa2",))):
        d = tmp_path / "util" / f"const{c}"
        d.mkdir(parents=True)
        for t in range(1, 6):
            for m in modes:
                (d / f"const{c}-trial{t}-{m}-extracted.csv").write_text("")
    flights = rcv.training_flights(tmp_path)
    assert len(flights) == 12
    assert all("trial5" not in f.path.name and f.trial in (1, 2, 3, 4) for f in flights)
    assert sum(f.mode == "tdoa3" for f in flights) == 4
    assert flights[0].label == "const1-trial1-tdoa2"


def test_without_fold_networks_it_exits_2(rcv: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path / "util" / "const1"
    d.mkdir(parents=True)
    for t in range(1, 5):                  # flights are there: the missing fold networks are the reason
        (d / f"const1-trial{t}-tdoa2-extracted.csv").write_text("")
    monkeypatch.setattr(sys, "argv", ["replay_cv.py", "--data", str(tmp_path), "--folds", str(tmp_path / "none")])
    assert rcv.main() == 2
    assert "util_fold_trial1.npz" in capsys.readouterr().err


def test_trials_outside_1_to_4_are_refused(rcv: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "argv", ["replay_cv.py", "--data", str(tmp_path), "--trials", "5"])
    assert rcv.main() == 2
