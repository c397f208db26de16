"""The Crazyflie uSD flights in a campaign (harness/campaign/recorded_usd.py) and the fixed split of the
real-flight network (harness/biasnet/recipes.py): no shared data needed, the logs are empty stand-ins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.report.data import RunMetrics

from harness.biasnet.recipes import (CF_USD_EVAL, CF_USD_LOS, CF_USD_SHELF, cf_usd_heldout_files, cf_usd_shelf_files,
                                     cf_usd_train_files)
from harness.campaign.plan import UTIL_ANCHORS, UTIL_HELD_OUT, CampaignOptions, plan_campaign


def _fake_data(root: Path) -> Path:
    """Stand-ins for the logs (and the UTIL TDoA files a TDoA campaign also asks for): the plan only looks."""
    for rel in (*CF_USD_LOS, *CF_USD_SHELF, *UTIL_HELD_OUT, UTIL_ANCHORS):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(b"\xbc")
    return root


def test_the_real_flight_split_is_fixed_by_flight_and_never_trains_on_evaluation_or_shelf(tmp_path: Path) -> None:
    data = _fake_data(tmp_path)
    train = [p.name for p in cf_usd_train_files(data)]
    assert [p.name for p in cf_usd_heldout_files(data)] == ["0425-traj3", "0425-traj8", "0425-traj13", "0425-traj18"]
    assert [p.name for p in cf_usd_shelf_files(data)] == ["0426-traj3", "0426-traj5"]
    assert train == ["0425-traj1", "0425-traj14", "0425-traj2", "0425-traj15", "0425-traj4", "0425-traj16",
                     "0425-traj5", "0425-traj17", "0425-traj6", "0425-traj7"]   # TDoA2 and TDoA3 alternate
    assert not set(train) & {Path(r).name for r in (*CF_USD_EVAL, *CF_USD_SHELF)}
    (data / CF_USD_LOS[0]).unlink()                  # a missing log is left out, not an error
    assert "0425-traj1" not in [p.name for p in cf_usd_train_files(data)]


def test_campaign_replays_every_log_with_imu_and_uwb_only_and_the_network_only_where_unseen(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from harness.biasnet.network import BiasModel, init_network
    from harness.campaign import recorded_usd
    from harness.twin.features import LAYOUT_TDOA_POSE
    data = _fake_data(tmp_path / "data")
    model = tmp_path / "cf.npz"
    train_rels = [str(p.relative_to(data)) for p in cf_usd_train_files(data)]
    BiasModel(tdoa=init_network(LAYOUT_TDOA_POSE, np.full(9, -1.0), np.full(9, 1.0), -0.5, 0.5,
                                np.random.default_rng(1)), meta={"tdoa_trained_on": train_rels}).save(model)
    monkeypatch.setattr(recorded_usd, "CF_MODEL", model)
    runs, notes = plan_campaign(CampaignOptions(seeds=0, modes=("tdoa",), latency_runs=False, data_dir=data,
                                                configs=("none", "outlier", "outlier+nn")))
    cf = [r for r in runs if recorded_usd.is_usd(r.flight.trajectory)]
    assert len({r.flight.path for r in cf}) == 16
    assert all(r.model == str(model) for r in cf)
    nn = {(Path(r.flight.path or "").name, r.flight.uwb_only) for r in cf if r.config == "outlier+nn"}
    # with the IMU only (UWB-only has no attitude for the pose network), and only on flights it never saw
    assert nn == {(Path(r).name, False) for r in (*CF_USD_EVAL, *CF_USD_SHELF)}
    assert len(cf) == 16 * 2 * 2 + 6
    assert {r.flight.uwb_only for r in cf if r.config == "outlier"} == {True, False}
    # one note per reason and network, naming the flights (not one per flight)
    trained = [n for n in notes if "was trained on it" in n]
    blind = [n for n in notes if "replayed UWB-only" in n]
    assert len(trained) == 1 and trained[0].startswith("cf-0425-traj1, cf-0425-traj2, ")
    assert len(blind) == 1 and blind[0].count("-uwb") == 16
    # stand-in logs cannot be calibrated: read with UTIL's lever arm, and the campaign says so
    assert all(r.flight.lever_arm is None for r in cf) and any("UTIL's lever arm" in n for n in notes)
    assert recorded_usd.usd_role("cf-0425-traj13-uwb") == "held-out"
    assert recorded_usd.usd_role("cf-0426-traj5") == "shelf" and recorded_usd.usd_role("cf-0425-traj1") == "training"
    assert len({r.run_id for r in runs}) == len(runs)


def _run(trajectory: str, config: str, flight_rmse: float, ground_rmse: float) -> RunMetrics:
    t = np.arange(4, dtype=np.float64)
    empty = np.zeros(0, np.float32)
    return RunMetrics(run_id=f"rec-tdoa-{trajectory}-{config}", flight_id=f"rec-tdoa-{trajectory}", source="recorded",
                      mode="tdoa", trajectory=trajectory, seed=None, config=config, measurements=10, results=10,
                      lost=0, refused=0, rmse=flight_rmse + ground_rmse, rmse_xy=0.0, rmse_z=0.0, max_error=1.0,
                      status_counts={}, err_t_s=t, err_mean=np.full(4, flight_rmse), compute_us=empty, rtt_us=empty,
                      kind=1, device_stats=None,
                      phases={"flight": {"rmse": flight_rmse}, "ground": {"rmse": ground_rmse}},
                      attitude={"angle_p50_deg": 1.5} if not trajectory.endswith("-uwb") else None)


def test_report_section_splits_the_crazyflie_logs_by_role_replay_and_phase() -> None:
    from harness.report.data import CampaignData
    from harness.report.summary import accuracy_section
    from harness.report.usd_section import _attitude_table, _rmse_tables, error_time_figure, usd_summary
    runs = [_run("cf-0425-traj3", "outlier", 0.20, 2.0), _run("cf-0425-traj3", "outlier+nn", 0.15, 2.5),
            _run("cf-0425-traj3-uwb", "outlier", 0.25, 3.0), _run("cf-0425-traj3-tof", "outlier", 0.10, 0.05),
            _run("cf-0425-traj3-tof", "outlier+nn", 0.08, 0.05), _run("cf-0425-traj1", "outlier", 0.30, 1.0),
            _run("cf-0425-traj1-uwb", "outlier", 0.40, 1.0), _run("util-const1-trial5-tdoa2", "outlier", 0.1, 0.0)]
    data = CampaignData(root=Path("."), manifest={}, runs=runs, failures=[], missing=[], devices=[])
    s = usd_summary(data)
    assert set(s["flights"]) == {"0425-traj3", "0425-traj1"}
    t3 = s["flights"]["0425-traj3"]
    assert t3["role"] == "held-out" and s["flights"]["0425-traj1"]["role"] == "training"
    assert t3["rmse_flight"] == {"imu outlier": 0.20, "imu outlier+nn": 0.15, "uwb outlier": 0.25,
                                 "tof outlier": 0.10, "tof outlier+nn": 0.08}
    assert t3["rmse"]["imu outlier+nn"] == pytest.approx(2.65)
    assert t3["attitude"] == {"imu outlier": 1.5, "imu outlier+nn": 1.5, "tof outlier": 1.5, "tof outlier+nn": 1.5}
    assert s["means_flight"]["training"] == {"imu outlier": 0.30, "uwb outlier": 0.40}
    per_flight, means = _rmse_tables(s, "rmse_flight", "means_flight", "")
    row = {r[0]: r for r in per_flight.rows}["0425-traj3"]
    assert row[-3:] == ["-25.0 %", "-20.0 %", "-20.0 %"]  # network vs outlier rejection, with ToF, IMU vs UWB-only
    assert {r[0]: r for r in per_flight.rows}["0425-traj1"][-3:] == ["-", "-", "-25.0 %"]
    assert [r[:2] for r in means.rows] == [["held-out", "1"], ["training", "1"]]
    att = _attitude_table(s)[0]
    assert att.headers[2:] == ["IMU + outlier", "IMU + outlier + NN", "IMU + ToF + outlier", "IMU + ToF + outlier + NN"]
    assert att.rows[0] == ["0425-traj1", "training", "1.50", "-", "-", "-"]
    fig = error_time_figure(data)
    assert fig is not None and len(fig.axes) == 1        # only the flight the network never saw
    # the UTIL/rcv recorded summary keeps its own flights
    assert [f["flight_id"] for f in accuracy_section(data)["recorded"]["flights"]] == ["rec-tdoa-util-const1-trial5-tdoa2"]


def test_report_section_has_a_column_for_every_run_flown_and_the_logs_in_natural_order() -> None:
    """The ToF replays' no-rejection runs and further configurations (outlier+nn+std) are flown by the default
    campaign: each has its column; logs sort as 0425-traj2 < 0425-traj3 < 0425-traj13 (not as strings)."""
    from harness.report.data import CampaignData
    from harness.report.usd_section import _rmse_tables, columns, usd_summary
    runs = [_run(f"cf-0425-traj{n}{suffix}", cfg, 0.1 * n, 1.0) for n in (13, 3, 2)
            for suffix, cfgs in (("", ("none", "outlier", "outlier+nn", "outlier+nn+std")), ("-uwb", ("none", "outlier")),
                                 ("-tof", ("none", "outlier", "outlier+nn", "outlier+nn+std")))
            for cfg in cfgs]
    s = usd_summary(CampaignData(root=Path("."), manifest={}, runs=runs, failures=[], missing=[], devices=[]))
    assert list(s["flights"]) == ["0425-traj2", "0425-traj3", "0425-traj13"]
    assert list(columns(s).values()) == [
        "UWB-only", "UWB-only + outlier", "IMU", "IMU + outlier", "IMU + outlier + NN", "IMU + outlier + NN + std",
        "IMU + ToF", "IMU + ToF + outlier", "IMU + ToF + outlier + NN", "IMU + ToF + outlier + NN + std"]
    per_flight, _ = _rmse_tables(s, "rmse_flight", "means_flight", "")
    row = {r[0]: r for r in per_flight.rows}["0425-traj13"]
    assert row[per_flight.headers.index("IMU + ToF")] == "1.300"
    assert len(row) == len(per_flight.headers) == 15


def test_a_calibrated_flight_survives_the_plan_file_round_trip() -> None:
    """Shards and workers read the plan back from JSON: the lever arm comes back as a list, the spec must
    still equal its original and group by flight."""
    import json
    from harness.campaign.flight_spec import FlightSpec
    from harness.campaign.plan import RunSpec, group_by_flight
    spec = FlightSpec(source="recorded", mode="tdoa", trajectory="cf-0425-traj3", path="/d/0425-traj3",
                      lever_arm=(0.037, -0.0167, 0.1458))
    runs = [RunSpec(flight=spec, config=c, firmware="fw") for c in ("outlier", "outlier+nn")]
    back = [RunSpec.from_dict(json.loads(json.dumps(r.as_dict()))) for r in runs]
    assert back == runs and back[0].flight.lever_arm == (0.037, -0.0167, 0.1458)
    assert [len(g) for g in group_by_flight(back)] == [2]
