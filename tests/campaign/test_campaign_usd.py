"""The Crazyflie uSD flights in a campaign (harness/campaign/recorded_usd.py) and the fixed split of the
real-flight network (harness/biasnet/recipes.py): no shared data needed, the logs are empty stand-ins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.biasnet.recipes import (CF_USD_EVAL, CF_USD_LOS, CF_USD_SHELF, cf_usd_heldout_files, cf_usd_shelf_files,
                                     cf_usd_train_files)
from harness.campaign.plan import CampaignOptions, plan_campaign


def _fake_data(root: Path) -> Path:
    for rel in (*CF_USD_LOS, *CF_USD_SHELF):
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
    assert any("was trained on it" in n for n in notes)
    assert recorded_usd.usd_role("cf-0425-traj13-uwb") == "held-out"
    assert recorded_usd.usd_role("cf-0426-traj5") == "shelf" and recorded_usd.usd_role("cf-0425-traj1") == "training"
    assert len({r.run_id for r in runs}) == len(runs)
