"""Calibration of the simulator against the real recordings: the statistics themselves (hand numbers),
the rcv_twr reader's errors, and the default simulator within 25 % of the real LOS TDoA statistics
(trial-level; skipped when ../shared/data is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.calibrate import plots, rcv_twr, stats, util_tdoa
from harness.cli import main as cli_main
from harness.paths import shared_data_dir

DATA = shared_data_dir()
needs_data = pytest.mark.skipif(not (DATA / "util" / "anchors.csv").is_file(),
                                reason=f"real data not found at {DATA} (set UWB_HIL_DATA)")


def test_error_stats_on_hand_numbers() -> None:
    # pair (0,1): errors +0.1 -> mean +0.1; reverse pair (1,0) measured -0.1 is the same pair, same sign
    # after canonicalisation; pair (1,2): -0.1. One 2 m outlier: counted in the tails, not in mean/std.
    e = np.array([0.1, 0.1, -0.1, -0.1, -0.1, 2.0])
    a = np.array([0, 0, 1, 1, 1, 1])
    b = np.array([1, 1, 0, 2, 2, 2])
    s = stats.error_stats(e, a, b)
    assert s.n == 6
    assert s.pair_means == pytest.approx({"0-1": 0.1, "1-2": -0.1})
    assert s.pair_spread == pytest.approx(0.1)
    assert s.frac_gt_03 == pytest.approx(1 / 6) and s.frac_gt_1 == pytest.approx(1 / 6)
    assert s.mean == pytest.approx(-0.02) and s.std == pytest.approx(np.std(e[:5]))
    # white noise from successive differences within a pair: constant pairs -> 0
    assert s.noise == pytest.approx(0.0)
    twr = stats.error_stats(np.array([0.2, 0.3, 0.2, 0.3, 0.2, 0.3]), np.array([1, 1, 1, 2, 2, 2]))
    assert twr.pair_means == pytest.approx({"1": 0.7 / 3, "2": 0.8 / 3})
    assert twr.pair_spread == pytest.approx(0.05 / 3)
    assert twr.noise == pytest.approx(0.1 / np.sqrt(2))   # differences +-0.1 -> std 0.1
    with pytest.raises(stats.CalibrationError):
        stats.error_stats(np.zeros(0), np.zeros(0, dtype=int))


def test_rcv_reader_names_file_line_and_field(tmp_path: Path) -> None:
    head = ("Time,Address,Range,Rxpower,Position X,Position Y,Position Z,Orientation X,Orientation Y,"
            "Orientation Z,Orientation W\n")
    good = "2024-06-09 19:39:13.438740,81,1.45,-62.67,0.05,-0.003,0.076,0.0,0.0,0.0,1.0\n"
    p = tmp_path / "anchor_1.csv"
    p.write_text(head + good + good.replace("1.45", "1.50").replace("13.43", "13.53"))
    t, rng, pos, quat = rcv_twr.read_rcv_ranges(p)
    assert rng.tolist() == [1.45, 1.50] and t[1] - t[0] == pytest.approx(0.1)
    assert np.allclose(quat, [[1, 0, 0, 0]] * 2) and pos.shape == (2, 3)
    p.write_text(head + good + good.replace("1.45", "x"))
    with pytest.raises(stats.CalibrationError, match=r"anchor_1.csv:3: a numeric field"):
        rcv_twr.read_rcv_ranges(p)
    p.write_text(head + "yesterday" + good[26:])
    with pytest.raises(stats.CalibrationError, match=r"anchor_1.csv:2: field Time"):
        rcv_twr.read_rcv_ranges(p)
    p.write_text("Time,Range\n")
    with pytest.raises(stats.CalibrationError, match=r"anchor_1.csv:1: expected header"):
        rcv_twr.read_rcv_ranges(p)
    with pytest.raises(stats.CalibrationError, match="not found"):
        rcv_twr.read_rcv_ranges(tmp_path / "nope.csv")


def test_calibrate_command_reports_missing_data(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["calibrate", "--data", str(tmp_path / "none")]) == 2
    assert "not found" in capsys.readouterr().err


@needs_data
def test_default_simulator_reproduces_real_los_tdoa_within_25_percent() -> None:
    """UTIL const1/const2 TDoA2 (10 trials) vs 3 simulated 60 s campaign flights in the same
    constellations: error std and per-pair bias spread within 25 %, trial-level."""
    group = util_tdoa.UTIL_GROUPS[0]
    _, real = util_tdoa.real_util_trials(DATA, group)
    _, sim = util_tdoa.sim_util_trials(DATA, group, n_trials=3, duration_s=60.0)
    r, s = stats.trial_summary(real), stats.trial_summary(sim)
    assert r["std"]["mean"] == pytest.approx(0.095, abs=0.02)      # the data README's ~0.09 m
    for key in ("std", "pair_spread"):
        ratio = s[key]["mean"] / r[key]["mean"]
        assert 0.75 <= ratio <= 1.25, (key, s[key]["mean"], r[key]["mean"])
    # the white part is the same size too, and the LOS tails are rare in both
    assert s["noise"]["mean"] == pytest.approx(r["noise"]["mean"], rel=0.25)
    assert s["frac_gt_0.3"]["mean"] < 0.01 and r["frac_gt_0.3"]["mean"] < 0.01
    assert s["frac_gt_1"]["mean"] < 0.001


@needs_data
def test_twr_pose_dependence_is_computed_for_real_and_simulated(tmp_path: Path) -> None:
    links = rcv_twr.rcv_twr_links(DATA)
    assert set(np.unique(links.sequence).tolist()) == {1, 2, 3, 4, 5}
    dep = rcv_twr.twr_dependence(links)
    for key in ("az_anchor", "el_anchor", "az_tag", "el_tag"):
        amp = dep[key]["amplitude"]
        assert 0.0 < amp["sim"] < 0.2 and 0.0 < amp["real"] < 0.2
    # the real heading sweep shows a pose dependence of several cm, and the simulator has one too
    assert dep["az_tag"]["amplitude"]["real"] > 0.01 and dep["az_tag"]["amplitude"]["sim"] > 0.01
    twr = rcv_twr.twr_stats(links)
    assert twr["real"]["median"] == pytest.approx(0.25, abs=0.05)   # rcv radios' antenna-delay offset
    written = plots.write_plots(tmp_path, links, dep, [])
    assert [p.name for p in written] == ["twr_error_vs_angle.png"] and written[0].stat().st_size > 10_000
