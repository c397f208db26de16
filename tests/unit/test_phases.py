"""Phases of a run (flight / ground, report/phases.py), the verdict judging the flight phase only, and the
firmware's attitude error against the truth: on a synthetic flight with a stubbed results array (numbers
known by construction), and end to end on the smallest shared Crazyflie uSD log (skipped without it)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from harness import cli, cli_verdict
from harness.config import MODE_IMU, MODE_UWB_ONLY, EstimatorConfig
from harness.flight.data import KIND_TWR, Anchors, Flight, Truth, UwbStream
from harness.flight.trajectory import quat_to_euler
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir
from harness.report.data import CampaignData, RunMetrics
from harness.report.metrics import accuracy_summary
from harness.report.phases import add_phases, attitude_errors, attitude_summary, quat_angle_deg
from harness.report.recorded_phases import phase_table
from harness.report.summary import accuracy_section
from harness.report.verdict import Criteria, evaluate
from harness.run.source import RunSource
from harness.stream.results_file import OUTCOME_RESULT, RESULTS_DTYPE
from harness.stream.streamer import Pacing, RunResult
from protocol.framing import DecoderErrors
from protocol.messages import Status

T_US = np.arange(0, 10_000_000, 10_000, dtype=np.int64)     # 10 s at 100 Hz
GROUND = (T_US < 2_000_000) | (T_US >= 8_000_000)            # tag on the floor before 2 s and after 8 s
FLIGHT_ERR, GROUND_ERR = np.array([0.1, 0.0, 0.2]), np.array([0.0, 0.0, 1.5])
ROLL_OFFSET_DEG, YAW_OFFSET_DEG = 3.0, 10.0                   # estimate = truth rotated about body x / body z


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, av, bw, bv = a[:, :1], a[:, 1:], b[:, :1], b[:, 1:]
    return np.hstack([aw * bw - np.sum(av * bv, axis=1, keepdims=True), aw * bv + bw * av + np.cross(av, bv)])


def _axis_quat(axis: int, deg: np.ndarray) -> np.ndarray:
    half = np.radians(np.broadcast_to(deg, T_US.shape)) / 2
    q = np.zeros((len(T_US), 4))
    q[:, 0], q[:, 1 + axis] = np.cos(half), np.sin(half)
    return q


def synthetic(tag_low: bool = True) -> tuple[RunResult, Flight]:
    """Truth: tag at 0.1 m on the ground (1.0 m in flight), level, yaw sweeping to 175 deg (the ground phase
    after landing sits near +-180, where a yaw error wraps). Estimate: truth + a known error per phase."""
    z = np.where(GROUND & tag_low, 0.1, 1.0)
    pos = np.stack([np.linspace(-1, 1, len(T_US)), np.zeros(len(T_US)), z], axis=1)
    q_true = _axis_quat(2, np.minimum(np.linspace(-150, 200, len(T_US)), 175.0))
    anchors = np.array([[-3.0, -3, 0.2], [3, -3, 0.2], [3, 3, 2.5], [-3, 3, 2.5]])
    a = np.arange(len(T_US)) % 4
    uwb = UwbStream(KIND_TWR, T_US, a, np.full(len(T_US), -1), np.linalg.norm(pos - anchors[a], axis=1))
    flight = Flight("phases", Anchors(np.arange(4), anchors), uwb, Truth(T_US, pos, quat=q_true))
    res = np.zeros(len(T_US), dtype=RESULTS_DTYPE)
    res["outcome"], res["t_us"], res["status"] = OUTCOME_RESULT, T_US, Status.ACCEPTED
    err = np.where(GROUND[:, None] & tag_low, GROUND_ERR, FLIGHT_ERR)
    for k, name in enumerate(("px", "py", "pz")):
        res[name] = pos[:, k] + err[:, k]
    off = np.where(GROUND[:, None], _axis_quat(2, YAW_OFFSET_DEG), _axis_quat(0, ROLL_OFFSET_DEG))
    q_est = -_qmul(q_true, off)        # the sign of a quaternion is no error
    for k, name in enumerate(("qw", "qx", "qy", "qz")):
        res[name] = q_est[:, k]
    run = RunResult(flight="phases", config=replace(EstimatorConfig(), mode=MODE_IMU), pacing=Pacing(),
                    results=res, stats=None, decoder_errors=DecoderErrors())
    return run, flight


def accuracy_with_phases(run: RunResult, flight: Flight, flight_above: float = 0.4) -> dict[str, Any]:
    """The `accuracy` of a run summary as summarize_run assembles it."""
    summary: dict[str, Any] = {"accuracy": accuracy_summary(run, flight).as_dict()}
    add_phases(summary, run, flight, flight_above)
    return summary["accuracy"]


def test_phase_split_numbers() -> None:
    run, flight = synthetic()
    acc = accuracy_with_phases(run, flight)
    fl, gr = acc["phases"]["flight"], acc["phases"]["ground"]
    assert acc["flight_above"] == 0.4 and fl["n"] == np.count_nonzero(~GROUND) and gr["n"] == np.count_nonzero(GROUND)
    assert fl["n"] + gr["n"] == acc["n"] == len(T_US)
    assert fl["rmse"] == pytest.approx(np.linalg.norm(FLIGHT_ERR), abs=1e-5)
    assert fl["rmse_xy"] == pytest.approx(0.1, abs=1e-5) and fl["rmse_z"] == pytest.approx(0.2, abs=1e-5)
    assert fl["z_mean_error"] == pytest.approx(0.2, abs=1e-5) and fl["accepted"] == fl["n"]
    assert gr["rmse"] == pytest.approx(1.5, abs=1e-5) and gr["z_mean_error"] == pytest.approx(1.5, abs=1e-5)
    share = gr["n"] / acc["n"]
    assert acc["rmse"] == pytest.approx(np.sqrt(share * 1.5 ** 2 + (1 - share) * 0.05), abs=1e-5)
    assert "phases" not in accuracy_with_phases(run, flight, flight_above=0.05)   # nothing below 5 cm


def test_a_flight_that_never_goes_below_has_one_phase() -> None:
    run, flight = synthetic(tag_low=False)
    acc = accuracy_with_phases(run, flight)
    assert "phases" not in acc and "flight_above" not in acc
    att = attitude_summary(run, flight)
    assert att is not None and "phases" not in att
    verdict = evaluate(_summary(acc), Criteria(max_rmse=0.3))
    rmse = next(c for c in verdict.checks if c.name == "rmse")
    assert rmse.detail == "" and "ground_phase" not in [c.name for c in verdict.checks]


def _summary(acc: dict[str, Any]) -> dict[str, Any]:
    return {"accuracy": acc, "health": {"divergences": 0, "non_finite": 0, "not_pd": 0},
            "geometry": {"z_observable": True, "xy_observable": True}}


def test_verdict_judges_the_flight_phase_and_reports_the_ground() -> None:
    run, flight = synthetic()
    acc = accuracy_with_phases(run, flight)
    assert acc["rmse"] > 0.5                       # the whole run would fail --max-rmse 0.3
    verdict = evaluate(_summary(acc), Criteria(max_rmse=0.3, max_rmse_xy=0.15))
    assert verdict.passed, verdict.reason()
    checks = {c.name: c for c in verdict.checks}
    n_fl = acc["phases"]["flight"]["n"]
    for name in ("rmse", "rmse_xy"):
        assert f"flight phase, truth above 0.4 m: {n_fl} of {len(T_US)} measurements" in checks[name].detail
    assert checks["rmse"].value == pytest.approx(acc["phases"]["flight"]["rmse"])
    ground = checks["ground_phase"]
    assert ground.passed and ground.threshold is None and ground.value == pytest.approx(1.5, abs=1e-5)
    assert "not judged" in ground.detail and f"{acc['phases']['ground']['n']} measurements" in ground.detail
    failed = evaluate(_summary(acc), Criteria(max_rmse=0.2))
    assert not failed.passed and "flight phase" in failed.reason()
    sick = evaluate({**_summary(acc), "health": {"divergences": 2}}, Criteria(max_rmse=0.3))
    assert [c.name for c in sick.failures()] == ["diverged"]      # health still covers the whole run


def test_attitude_error_of_a_known_rotation_offset() -> None:
    run, flight = synthetic()
    att = attitude_summary(run, flight)
    assert att is not None and att["n"] == len(T_US)
    fl, gr = att["phases"]["flight"], att["phases"]["ground"]
    assert fl["angle_p50_deg"] == pytest.approx(ROLL_OFFSET_DEG, abs=1e-3)
    assert fl["angle_p95_deg"] == pytest.approx(ROLL_OFFSET_DEG, abs=1e-3)
    assert fl["roll_mean_deg"] == pytest.approx(ROLL_OFFSET_DEG, abs=1e-3)
    assert fl["roll_rms_deg"] == pytest.approx(ROLL_OFFSET_DEG, abs=1e-3)
    assert abs(fl["pitch_mean_deg"]) < 1e-3 and abs(fl["yaw_rms_deg"]) < 1e-3
    # the yaw error wraps: truth 175 deg, estimate 185 = -175 deg, error +10 (not -350)
    assert gr["angle_p50_deg"] == pytest.approx(YAW_OFFSET_DEG, abs=1e-3)
    assert gr["yaw_mean_deg"] == pytest.approx(YAW_OFFSET_DEG, abs=1e-3)
    assert gr["yaw_rms_deg"] == pytest.approx(YAW_OFFSET_DEG, abs=1e-3) and abs(gr["roll_mean_deg"]) < 1e-3
    share = np.count_nonzero(GROUND) / len(T_US)
    assert att["yaw_mean_deg"] == pytest.approx(share * YAW_OFFSET_DEG, abs=1e-3)
    assert np.degrees(quat_to_euler(flight.truth.quat[-1:]))[0, 2] == pytest.approx(175.0)
    for whole, blocked in zip(attitude_errors(run, flight), attitude_errors(run, flight, block=7)):
        np.testing.assert_array_equal(whole, blocked)             # computed in blocks of rows: same values


def test_attitude_angle_small_and_opposite_signs() -> None:
    q = np.array([[1.0, 0, 0, 0], [np.cos(0.5e-4), np.sin(0.5e-4), 0, 0]])
    np.testing.assert_allclose(quat_angle_deg(q[:1].repeat(2, 0), np.vstack([-q[0], q[1]])), [0.0, np.degrees(1e-4)],
                               atol=1e-9)


def test_no_attitude_error_without_an_estimate_or_a_truth() -> None:
    run, flight = synthetic()
    uwb_only = replace(run, config=replace(run.config, mode=MODE_UWB_ONLY))
    assert attitude_summary(uwb_only, flight) is None          # a level attitude held, nothing estimated
    assert attitude_summary(run, replace(flight, truth=replace(flight.truth, quat=None))) is None


def test_flight_above_kept_in_the_results_header() -> None:
    args = cli.build_parser().parse_args(["run", "--recording", "x", "--flight-above", "0.25"])
    again = RunSource.from_mapping(json.loads(json.dumps(RunSource.from_mapping(vars(args)).as_header())))
    assert again.flight_above == 0.25
    old_header = {k: v for k, v in RunSource().as_header().items() if k != "flight_above"}
    assert RunSource.from_mapping(old_header).flight_above == 0.4


SHARED_LOGS = sorted((shared_data_dir() / "cf_usd").glob("*/*-traj[0-9]*"))


@pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")
def test_shared_log_reports_phases_and_attitude(capsys: pytest.CaptureFixture[str]) -> None:
    """`uwb-hil run --recording <smallest shared log> --json` (~3 s): a ground phase, judged apart."""
    if not SHARED_LOGS:
        pytest.skip(f"shared data absent ({shared_data_dir() / 'cf_usd'})")
    path = min(SHARED_LOGS, key=lambda p: p.stat().st_size)
    rc = cli.main(["run", "--recording", str(path), "--json", "--max-rmse", "1000"])
    out = capsys.readouterr()
    assert rc in (0, 1), out.err
    s = json.loads(out.out)
    acc, att = s["accuracy"], s["attitude"]
    assert acc["flight_above"] == 0.4 and set(acc["phases"]) == {"flight", "ground"}
    assert acc["phases"]["flight"]["n"] + acc["phases"]["ground"]["n"] == acc["n"] == s["results"]
    assert acc["phases"]["ground"]["n"] > 0 and acc["phases"]["flight"]["n"] > acc["phases"]["ground"]["n"]
    assert set(att["phases"]) == {"flight", "ground"} and att["n"] == s["results"]
    assert {"angle_p50_deg", "angle_p95_deg", "roll_rms_deg", "pitch_mean_deg", "yaw_rms_deg"} <= set(att)
    assert 0 <= att["angle_p50_deg"] <= att["angle_p95_deg"] < 90
    checks = {c["name"]: c for c in s["verdict"]["checks"]}
    assert "flight phase, truth above 0.4 m" in checks["rmse"]["detail"] and checks["ground_phase"]["passed"]
    cli_verdict.print_phases(s)
    text = capsys.readouterr().out
    assert "flight phase (truth above 0.40 m)" in text and "ground phase (truth below 0.40 m)" in text
    assert "attitude error (firmware vs truth)" in text


# ------------------------------------------------------------------------------ campaign report
def _metrics(flight_id: str, config: str, run: RunResult, flight: Flight, trajectory: str = "real") -> RunMetrics:
    """A recorded run of the campaign as the report reads it, with the phases and attitude its stored summary
    carries (summarize_run)."""
    acc = accuracy_with_phases(run, flight)
    empty = np.zeros(0, np.float32)
    return RunMetrics(run_id=f"{flight_id}-{config}", flight_id=flight_id, source="recorded", mode="tdoa",
                      trajectory=trajectory, seed=None, config=config, measurements=acc["n"], results=acc["n"], lost=0,
                      refused=0, rmse=acc["rmse"], rmse_xy=acc["rmse_xy"], rmse_z=acc["rmse_z"],
                      max_error=acc["max_error"], status_counts={}, err_t_s=empty, err_mean=empty, compute_us=empty,
                      rtt_us=empty, kind=KIND_TWR, device_stats=None, phases=acc.get("phases"),
                      attitude=attitude_summary(run, flight))


def test_campaign_report_shows_the_flight_phase_and_attitude() -> None:
    run, flight = synthetic()
    level_run, level_flight = synthetic(tag_low=False)
    runs = [_metrics("0425-traj3", cfg, run, flight) for cfg in ("outlier", "outlier+nn")]
    runs.append(_metrics("sim-like", "outlier", level_run, level_flight))
    data = CampaignData(root=Path("."), manifest={}, runs=runs, failures=[], missing=[], devices=[])
    rows = {f["flight_id"]: f for f in accuracy_section(data)["recorded"]["flights"]}
    real = rows["0425-traj3"]
    assert real["rmse_flight_phase"]["outlier+nn"] == pytest.approx(np.linalg.norm(FLIGHT_ERR), abs=1e-5)
    assert real["rmse_ground_phase"]["outlier"] == pytest.approx(1.5, abs=1e-5)
    assert real["attitude_flight_phase"]["outlier+nn"]["angle_p50_deg"] == pytest.approx(ROLL_OFFSET_DEG, abs=1e-3)
    assert "rmse_flight_phase" not in rows["sim-like"]             # one phase: nothing to split
    table = phase_table(list(rows.values()))
    assert table is not None and table.headers[-1] == "attitude error p50 / p95 [deg] in flight (outlier+nn)"
    by_flight = {r[0]: r for r in table.rows}
    assert by_flight["0425-traj3"][1:] == ["0.224 / 1.500", "0.224 / 1.500", "3.0 / 3.0"]
    assert by_flight["sim-like"][1:] == ["- / -", "- / -", "- / -"]    # only an attitude error (in another config)
    assert phase_table([{"flight_id": "x", "rmse_outlier": 0.3}]) is None


def test_crazyflie_section_shows_the_flight_phase() -> None:
    """The campaign's Crazyflie section (report/usd_section.py): whole-flight and flight-phase RMSE per log,
    per (replay, configuration), and their means per role."""
    from harness.campaign.recorded_usd import LABEL_PREFIX, UWB_ONLY_SUFFIX
    from harness.report.usd_section import _rmse_tables, usd_summary
    run, flight = synthetic()
    label = LABEL_PREFIX + "0425-traj3"
    runs = [_metrics("a", "outlier", run, flight, label), _metrics("b", "outlier", run, flight, label + UWB_ONLY_SUFFIX)]
    data = CampaignData(root=Path("."), manifest={}, runs=runs, failures=[], missing=[], devices=[])
    summary = usd_summary(data)
    row = summary["flights"]["0425-traj3"]
    assert row["role"] == "held-out" and row["rmse"]["imu outlier"] == pytest.approx(runs[0].rmse)
    assert row["rmse_flight"] == pytest.approx({"imu outlier": np.linalg.norm(FLIGHT_ERR),
                                                "uwb outlier": np.linalg.norm(FLIGHT_ERR)}, abs=1e-5)
    assert summary["means_flight"]["held-out"]["imu outlier"] == pytest.approx(np.linalg.norm(FLIGHT_ERR), abs=1e-5)
    per_flight, means = _rmse_tables(summary, "rmse_flight", "means_flight", ", flight phase (truth above 0.4 m)")
    assert per_flight.caption == "Per flight, flight phase (truth above 0.4 m)"
    # a column for each (replay, configuration) flown, UWB-only first: no empty columns for runs not flown
    assert per_flight.headers[2:4] == ["UWB-only + outlier", "IMU + outlier"]
    assert per_flight.rows[0][:4] == ["0425-traj3", "held-out", "0.224", "0.224"] and means.rows[0][:2] == ["held-out", "1"]
