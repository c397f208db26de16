"""`uwb-hil tune` (harness/calibrate/tune.py): the grid is replayed through the twin, ranked (no resets first,
then mean flight RMSE), the pick written as a settings file `run --set @FILE` reads back; bad grids refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.calibrate.tune import GridAxis, Trial, grid_search, run_trial, settings_toml, write_settings
from harness.cli import main
from harness.config import EstimatorConfig, config_with
from harness.errors import InputError
from harness.flight.native import save_flight
from harness.flight.scenarios import scenario_flight


@pytest.fixture(scope="module")
def flights() -> list:
    # UWB-only TDoA circles with white noise of 0.1 m: a measurement std far below it lets the noise through
    return [scenario_flight("circle", mode="tdoa", duration_s=4.0, seed=s, noise="gaussian", noise_std=0.1)
            for s in (1, 2)]


def test_the_grid_is_ranked_by_mean_rmse_and_matches_single_trials(flights: list) -> None:
    axes = [GridAxis.parse("std_tdoa=0.02,0.1")]
    lines: list[str] = []
    trials = grid_search(flights, axes, "outlier", flight_above=-10.0, uwb_only=True, log=lines.append)
    assert [ln.split("]")[0].split(",")[0] for ln in lines] == ["[1/2", "[2/2"]     # one progress line each
    assert "std_tdoa=0.02: mean RMSE" in lines[0] and "std_tdoa=0.1: mean RMSE" in lines[1]
    assert [t.mean_rmse_m for t in trials] == sorted(t.mean_rmse_m for t in trials)
    assert {dict(t.settings)["std_tdoa"] for t in trials} == {0.02, 0.1}
    # the std of the noise beats one five times too small (it follows the noise)
    assert dict(trials[0].settings)["std_tdoa"] == 0.1
    assert trials[1].mean_rmse_m > trials[0].mean_rmse_m * 1.05
    again = run_trial(flights, "outlier", (), (("std_tdoa", 0.1),), -10.0, uwb_only=True)
    assert again.rmse_m == trials[0].rmse_m            # same machine, same numbers
    assert all(np.isfinite(t.rmse_m).all() for t in trials)


def test_a_diverging_combination_ranks_last() -> None:
    good = Trial((("std_tdoa", 0.3),), (0.5, 0.5), (0, 0))
    bad = Trial((("std_tdoa", 0.1),), (0.1, 0.1), (0, 2))
    assert sorted([bad, good], key=lambda t: (t.diverged, t.mean_rmse_m)) == [good, bad]


def test_settings_file_reads_back_through_set(tmp_path: Path) -> None:
    best = Trial((("std_tdoa", 0.45), ("proc_acc_xy", EstimatorConfig().proc_acc_xy)), (0.2,), (0,))
    path = tmp_path / "picked.toml"
    write_settings(path, settings_toml(best, ["a.csv"], "outlier", ["chi2_tdoa=9"], 4))
    cfg = config_with([f"@{path}"])
    assert cfg.std_tdoa == pytest.approx(0.45)
    assert cfg.chi2_tdoa == pytest.approx(9.0)                    # the base settings come along
    text = path.read_text()
    assert "proc_acc_xy" not in text                              # only what moves from the power-up values
    assert "a.csv" in text and "in-sample" in text.lower()


@pytest.mark.parametrize("grid, needle", [("std_tdoa", "FIELD=V1"), ("std_tdoa=0.1,x", "not a number"),
                                          ("no_such_field=1", "no_such_field"), ("std_tdoa=-1", "std_tdoa")])
def test_bad_grids_are_refused_naming_the_problem(grid: str, needle: str) -> None:
    with pytest.raises(InputError, match=needle):
        GridAxis.parse(grid)


def test_a_field_both_set_and_gridded_is_refused(flights: list) -> None:
    """`--set std_tdoa=0.3 --grid std_tdoa=0.1,0.2` silently tuned over the --set value; an unknown grid field
    was reported as a --set."""
    with pytest.raises(InputError, match="std_tdoa given both by --set and --grid"):
        grid_search(flights, [GridAxis.parse("std_tdoa=0.1,0.2")], "outlier", ["std_tdoa=0.3"])
    with pytest.raises(InputError, match=r"^--grid 'no_such_field=1': expected FIELD=VALUE"):
        GridAxis.parse("no_such_field=1")


def test_cli_writes_the_pick_and_exits_0(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    flight = scenario_flight("circle", mode="twr", duration_s=3.0, seed=3, noise="gaussian", noise_std=0.1)
    rec = save_flight(flight, tmp_path / "flight.npz")
    out = tmp_path / "pick.toml"
    code = main(["tune", "--recording", str(rec), "--uwb-only", "--grid", "std_twr=0.05,0.1",
                 "--flight-above", "-10", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    assert out.is_file() and "best: std_twr=" in capsys.readouterr().out


def test_cli_refuses_a_network_stage_without_a_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["tune", "--recording", str(tmp_path / "none.csv"), "--stages", "outlier+nn", "--grid",
                 "std_tdoa=0.1", "--out", str(tmp_path / "x.toml")])
    assert code == 2
    assert "--model" in capsys.readouterr().err
