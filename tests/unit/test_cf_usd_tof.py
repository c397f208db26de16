"""The flow deck's ToF ranger in Crazyflie uSD logs: estTOF decoded from a log written here (usd_writer.py) into
the flight's auxiliary stream, its offset from the tag point in the configuration, `--tof` / `--no-tof`, and a
shared log replayed with it end to end (docs/real-flights.md "The ToF ranger")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from harness import cli
from harness.config import EstimatorConfig
from harness.flight.data import KIND_TOF
from harness.flight.formats.cf_usd import read_usd_log
from harness.flight.formats.cf_usd_flight import TOF_BODY, UsdOptions
from harness.flight.loaders import load_recording
from harness.flight.run_config import config_for
from harness.flight.tof_offset import body_offset
from harness.kinds import MeasInput, kind_of
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir
from harness.twin.ekf import quat_to_rot
from protocol.messages import Status
from usd_writer import hover_log, write_anchors

SHARED = shared_data_dir() / "cf_usd"
#: the ranger's reading of the hovering log: body origin 1.2 m up, level, ranger TOF_BODY below it
RANGE_MM = round((1.2 + TOF_BODY[2]) * 1000)


@pytest.fixture
def log(tmp_path: Path) -> Path:
    write_anchors(tmp_path / "anchor_0101.npz")
    return hover_log(tof_mm=RANGE_MM).write(tmp_path / "0101-traj1")


def test_estTOF_decoded_into_the_auxiliary_stream(log: Path) -> None:
    raw = read_usd_log(log)
    assert raw.count("estTOF") == 50 and raw.events["estTOF"]["range.zrange"].dtype == np.uint16
    assert raw.times["estTOF"][0] == 1_007_000 and set(raw.events["estTOF"]["range.zrange"].tolist()) == {RANGE_MM}
    flight = load_recording(log, usd=UsdOptions(tof=True))
    aux = flight.aux
    assert aux is not None and aux.kind == KIND_TOF and len(aux) == 50     # all within the pose span
    np.testing.assert_allclose(aux.value, RANGE_MM * 1e-3)
    assert np.all(aux.anchor_a == -1) and aux.t_us.dtype == np.int64
    assert "estTOF" not in flight.meta["ignored_events"] and flight.meta["events"]["estTOF"] == 50
    # the ranger relative to the tag point (the truth and the state): TOF_BODY - the tag's lever arm
    lever = flight.meta["tag_lever_arm_m"]
    np.testing.assert_allclose(flight.meta["tof_offset_m"], np.subtract(TOF_BODY, lever))
    cfg = config_for(flight, EstimatorConfig())
    np.testing.assert_allclose((cfg.tof_x, cfg.tof_y, cfg.tof_z), flight.meta["tof_offset_m"], atol=1e-7)
    # the model at the true tag pose predicts the reading
    t = int(aux.t_us[0])
    x = MeasInput(flight.truth.position_at([t])[0], quat_to_rot(flight.truth.quat_at([t])[0]), None, None,
                  float(aux.value[0]), cfg)
    status, h, H3 = kind_of(KIND_TOF).model(x)
    assert status == Status.ACCEPTED and abs(h - RANGE_MM * 1e-3) < 1e-6
    np.testing.assert_allclose(H3, [0.0, 0.0, 1.0], atol=1e-9)


def test_without_tof_no_auxiliary_stream(log: Path) -> None:
    flight = load_recording(log, usd=UsdOptions(tof=False))
    assert flight.aux is None and flight.meta["events"]["estTOF"] == 50


def test_tof_option_parsed_and_kept_in_a_results_header(log: Path) -> None:
    from harness.run.source import RunSource, make_flight
    for opt, want in (("--tof", True), ("--no-tof", False)):
        args = cli.build_parser().parse_args(["run", "--recording", str(log), opt])
        again = RunSource.from_mapping(json.loads(json.dumps(RunSource.from_mapping(vars(args)).as_header())))
        assert again.tof is want and (make_flight(again).aux is not None) is want


def test_body_offset_measured_on_a_log(log: Path) -> None:
    """tof_offset: reading - body z / cos(tilt), in flight (body above 0.4 m)."""
    offset, per_log = body_offset([log])
    assert abs(offset - TOF_BODY[2]) < 1e-6 and per_log[0].flight.size == 50 and per_log[0].floor.size == 0


needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


@needs_fw
def test_shared_log_with_tof_never_resets(capsys: pytest.CaptureFixture[str]) -> None:
    """0425-traj1 (without ToF: a SPEED reset at landing, its ground phase 1.4 m RMSE) through the host firmware
    with the ranger: no supervisor reset, z in flight within centimetres (~2 s)."""
    path = SHARED / "0425" / "0425-traj1"
    if not path.is_file():
        pytest.skip(f"shared data absent ({path})")
    rc = cli.main(["run", "--recording", str(path), "--stages", "outlier", "--tof", "--json"])
    out = capsys.readouterr()
    summary = json.loads(out.out)
    assert rc == 0, out.err
    assert summary["health"]["divergences"] == 0
    aux = load_recording(path, usd=UsdOptions(tof=True)).aux
    assert aux is not None and summary["auxiliary"] == {"kind": "tof", "measurements": len(aux)}
    flight = summary["accuracy"]["phases"]["flight"]
    assert flight["rmse_z"] < 0.03 and abs(flight["z_mean_error"]) < 0.02 and flight["rmse"] < 0.35


def test_campaign_replays_a_log_with_the_ranger_only_where_it_has_readings(tmp_path: Path) -> None:
    """The recorded section plans IMU, UWB-only and, for a log with estTOF readings, IMU + ToF (run's default);
    the worker reads that replay with the ranger, the others without (harness/campaign/recorded_usd.py)."""
    from harness.biasnet.recipes import CF_USD_LOS
    from harness.campaign.recorded_usd import replay_of, usd_flights
    from harness.campaign.worker import _base_flight
    with_tof, without = tmp_path / CF_USD_LOS[0], tmp_path / CF_USD_LOS[1]
    with_tof.parent.mkdir(parents=True)
    write_anchors(with_tof.parent / "anchor_0425.npz")
    hover_log(tof_mm=RANGE_MM).write(with_tof)
    hover_log().write(without)
    flights, notes, _ = usd_flights(tmp_path, with_models=False)
    replays = {(Path(f.path or "").name, replay_of(f.trajectory)): f for f in flights}
    assert set(replays) == {(with_tof.name, "imu"), (with_tof.name, "uwb"), (with_tof.name, "tof"),
                            (without.name, "imu"), (without.name, "uwb")}
    tof = replays[(with_tof.name, "tof")]
    assert tof.tof and not tof.uwb_only and tof.trajectory.endswith("-tof")
    assert _base_flight(tof).aux is not None and _base_flight(replays[(with_tof.name, "imu")]).aux is None
    assert any("ToF ranger where the log has its readings (1)" in n for n in notes)
    assert "tof" not in replays[(with_tof.name, "imu")].as_dict()       # fingerprints without the ranger unchanged
