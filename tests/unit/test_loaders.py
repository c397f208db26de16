"""Recorded-data loaders: synthetic fixtures with known answers, malformed files, every shared recording
(skipped without ../shared/data), and a real flight replayed through the device. The native format has its own
tests (test_native_format.py).

The fixtures in tests/fixtures/recordings, and the rcv_twr sequence written by `write_rcv_twr_mini`
(rcv_twr_mini.py), come
from exact geometry (noise-free values), so a loader that gets a convention wrong (TDoA sign, lever arm,
quaternion order, units) fails here. Real recordings are only read from ../shared/data.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, PRESETS, EstimatorConfig
from harness.flight.loaders import RecordingError, load_anchors, load_rcv_twr, load_recording, time_slice
from harness.flight.data import KIND_TDOA, KIND_TWR
from harness.flight.run_config import config_for
from harness.paths import shared_data_dir
from rcv_twr_mini import write_rcv_twr_mini

FIX = Path(__file__).parents[1] / "fixtures" / "recordings"
REDUCED = FIX / "const1-fixture-tdoa2.csv"
OFFICIAL = FIX / "const2-fixture-official.csv"
DATA = shared_data_dir()
UTIL_FILES = sorted((DATA / "util").glob("const*/*.csv")) if (DATA / "util").is_dir() else []
RCV_DIRS = sorted((DATA / "rcv_twr").glob("sequence*")) if (DATA / "rcv_twr").is_dir() else []
NO_DATA = f"shared data folder {DATA} is absent (real recordings are only in the project's data share / CI)"


# ------------------------------------------------------------------------------------ UTIL, reduced
def test_reduced_util_csv_fixture() -> None:
    f = load_recording(REDUCED)          # anchors.csv found next to it; constellation 1 from the name
    assert f.uwb.kind == KIND_TDOA and f.imu is None
    assert len(f.uwb) == 40 and len(f.truth.t_us) == 20
    assert f.uwb.t_us.dtype == np.int64 and f.uwb.t_us[0] == 10_000 and f.uwb.t_us[1] == 12_100
    assert (int(f.uwb.anchor_a[0]), int(f.uwb.anchor_b[0])) == (7, 0)
    # tag = Vicon body + 0.0908 m in world z (level assumption of the reduced layout)
    np.testing.assert_allclose(f.truth.pos[0], [1.0, 0.0, 1.0908], atol=1e-9)
    # value = d(tag, B) - d(tag, A): the fixture is noise-free, so true_value must reproduce it
    assert f.uwb.true_value is not None
    np.testing.assert_allclose(f.uwb.true_value, f.uwb.value, atol=2e-6)
    assert f.meta["format"] == "util-csv-8" and f.meta["constellation"] == 1 and f.meta["tdoa_mode"] == "tdoa2"
    assert f.meta["dropped"] == {}
    np.testing.assert_allclose(f.anchors.position(1), [-3.0, 4.0, 2.6])
    assert config_for(f).mode == MODE_UWB_ONLY   # no IMU -> the firmware's UWB-only mode


def test_official_util_csv_fixture_with_imu_and_attitude() -> None:
    f = load_recording(OFFICIAL, FIX / "anchors.csv")    # constellation 2 from the file name
    np.testing.assert_allclose(f.anchors.position(0), [-3.0, -4.0, 0.3])
    assert f.meta["format"] == "util-csv-27" and f.meta["constellation"] == 2
    assert f.imu is not None and len(f.imu) == 90
    np.testing.assert_allclose(f.imu.acc[5], [0.0, 0.0, 9.81])         # 1 g -> m/s^2
    np.testing.assert_allclose(f.imu.gyro[5], [0.0, 0.0, 0.5], atol=1e-9)  # 28.6479 deg/s -> rad/s
    assert f.imu.t_us[1] == 1000
    # quaternion columns (x, y, z, w) -> (w, x, y, z); roll 10 deg, yaw 90 deg at t = 0
    assert f.truth.quat is not None
    np.testing.assert_allclose(f.truth.quat[0], [0.704416026, 0.061628417, 0.061628417, 0.704416026], atol=1e-8)
    # the lever arm is rotated by the attitude: the noise-free TDoA values are reproduced to 1e-6 m only so
    # (the level assumption would be off by ~1 cm here)
    np.testing.assert_allclose(f.uwb.true_value, f.uwb.value, atol=2e-6)
    assert abs(f.truth.pos[0, 2] - (1.0 + 0.0908)) > 1e-3
    assert config_for(f).mode == MODE_IMU_THRUST    # a Crazyflie: the quadrotor model
    assert config_for(replace(f, meta={})).mode == MODE_IMU
    # its IMU tells the floor in every mode, UWB-only included; not for another vehicle, nor without IMU
    assert config_for(f, uwb_only=True).floor_imu == 1 and config_for(f).floor_imu == 1
    assert config_for(replace(f, meta={})).floor_imu == 0 and config_for(replace(f, imu=None)).floor_imu == 0


def test_util_survey_files_give_the_same_flight(tmp_path: Path) -> None:
    txt = load_anchors(FIX / "anchor_const1.txt")
    assert list(txt.ids) == list(range(8)) and txt.orientations is not None
    np.testing.assert_allclose(txt.orientations[0], [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
    npz = tmp_path / "anchor_const1.npz"
    q_xyzw = np.tile([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)], (8, 1))
    np.savez(npz, an_pos=txt.positions, an_quat=q_xyzw)
    survey = load_anchors(npz)
    np.testing.assert_array_equal(survey.positions, txt.positions)
    np.testing.assert_allclose(survey.orientations, txt.orientations)
    a = load_recording(REDUCED, npz)
    b = load_recording(REDUCED, FIX / "anchors.csv")
    np.testing.assert_array_equal(a.uwb.true_value, b.uwb.true_value)


def test_anchors_csv_needs_a_constellation_when_it_has_several(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"holds constellations \[1, 2\]"):
        load_anchors(FIX / "anchors.csv")
    assert load_anchors(FIX / "anchors.csv", constellation=2).positions[0, 2] == pytest.approx(0.3)
    unnamed = tmp_path / "flight.csv"
    shutil.copy(REDUCED, unnamed)
    with pytest.raises(RecordingError, match="say which one"):
        load_recording(unnamed, FIX / "anchors.csv")
    assert len(load_recording(unnamed, FIX / "anchors.csv", constellation=1).uwb) == 40
    with pytest.raises(RecordingError, match="no constellation 5"):
        load_recording(unnamed, FIX / "anchors.csv", constellation=5)


# ------------------------------------------------------------------------------------ malformed
@pytest.mark.parametrize("name, line, field, text", [
    ("const1-bad-truncated.csv", 41, None, "expected 8 fields"),
    ("const1-bad-columns.csv", 10, None, "expected 8 fields (as in the header), got 9"),
    ("const1-bad-nonnumeric.csv", 7, "tdoa_meas", "expected a number, got '1.2.3'"),
    ("const1-bad-nan.csv", 12, "tdoa_meas", "expected a finite number, got 'nan'"),
    ("const1-bad-backwards.csv", 20, "t_tdoa", "time goes backwards"),
    ("const1-bad-unknown-anchor.csv", 15, "idB", "unknown anchor 9"),
    ("const1-bad-stream-gap.csv", 6, "t_pose", "resumes here"),
])
def test_malformed_util_files_name_file_line_and_field(name: str, line: int, field: str | None, text: str) -> None:
    with pytest.raises(RecordingError) as info:
        load_recording(FIX / name)
    err = info.value
    assert err.path == FIX / name and err.line == line and err.field == field
    assert text in str(err) and name in str(err) and f"line {line}" in str(err)


def test_empty_and_missing_files() -> None:
    with pytest.raises(RecordingError, match="empty file") as info:
        load_recording(FIX / "const1-bad-empty.csv")
    assert info.value.line == 1
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        load_recording(FIX / "nope.csv")
    with pytest.raises(FileNotFoundError, match="no-anchors.csv"):
        load_recording(REDUCED, FIX / "no-anchors.csv")


def test_wrong_kind_of_file_is_explained(tmp_path: Path, rcv: Path) -> None:
    with pytest.raises(RecordingError, match="anchor file"):
        load_recording(FIX / "anchors.csv")
    with pytest.raises(RecordingError, match="pass the sequence directory"):
        load_recording(rcv / "anchor_1.csv")
    other = tmp_path / "other.csv"
    other.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(RecordingError, match="unknown recording format"):
        load_recording(other)
    with pytest.raises(RecordingError, match="not a recording"):
        load_recording(tmp_path)


def test_duplicate_rows_are_dropped_and_counted(tmp_path: Path) -> None:
    lines = REDUCED.read_text().splitlines()
    dup = tmp_path / "const1-dup.csv"
    dup.write_text("\n".join(lines[:6] + [lines[5]] + lines[6:]) + "\n")   # data row 5 repeated (pose too)
    # the repeated row also repeats a pose sample: that stream gets a duplicate as well
    f = load_recording(dup, FIX / "anchors.csv")
    assert len(f.uwb) == 40 and f.meta["dropped"] == {"duplicate_tdoa_rows": 1, "duplicate_pose_rows": 1}


def test_measurements_outside_the_truth_span_are_dropped_and_counted(tmp_path: Path) -> None:
    lines = REDUCED.read_text().splitlines()
    late = tmp_path / "const1-late.csv"
    late.write_text("\n".join(lines + ["0,1,0.5,0.200000,,,,"]) + "\n")   # 0.2 s: after the last pose (0.095 s)
    f = load_recording(late, FIX / "anchors.csv")
    assert len(f.uwb) == 40 and f.meta["dropped"] == {"tdoa_outside_truth_span": 1}


# ------------------------------------------------------------------------------------ rcv_twr
@pytest.fixture(scope="module")
def rcv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rcv_twr_mini(tmp_path_factory.mktemp("rcv") / "rcv_twr_mini")


def test_rcv_twr_fixture_sequence(rcv: Path) -> None:
    f = load_recording(rcv)
    assert f.uwb.kind == KIND_TWR and f.imu is None and f.name == "rcv_twr-rcv_twr_mini"
    assert len(f.uwb) == 27 and f.meta["dropped"] == {"nonpositive_range_anchor_2": 1}
    assert np.all(np.diff(f.uwb.t_us) >= 0) and set(f.uwb.anchor_a.tolist()) == {1, 2, 3, 4}
    assert np.all(f.uwb.anchor_b == -1)
    assert f.uwb.t_us[0] == 20_000            # microseconds since the first gt sample (19:39:13.000000)
    np.testing.assert_allclose(f.anchors.position(1), [2.0, 1.95, 1.045])     # + (0, -0.05, 0.045) offset
    assert f.anchors.orientations is not None
    np.testing.assert_allclose(f.anchors.orientations[0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(f.uwb.true_value, f.uwb.value, atol=0.0051)   # 1 cm range resolution
    assert f.meta["anchor_addresses"] == {"1": [81], "2": [82], "3": [83], "4": [84]}
    plain = load_recording(rcv, anchor_offset=None)
    np.testing.assert_allclose(plain.anchors.position(1), [2.0, 2.0, 1.0])
    assert np.max(np.abs(plain.uwb.true_value - plain.uwb.value)) > 0.01


def test_rcv_twr_antenna_offset_comes_from_the_data_readme(tmp_path: Path) -> None:
    """The offset is the data README's, not a constant in the code: none without such a README, a clear error
    when the README states it unreadably."""
    seq = write_rcv_twr_mini(tmp_path / "data" / "rcv_twr" / "seq")
    readme = seq.parent / "README.md"
    readme.replace(tmp_path / "data" / "README.md")          # one level up, as ../shared/data/README.md
    np.testing.assert_allclose(load_recording(seq).anchors.position(1), [2.0, 1.95, 1.045])
    (tmp_path / "data" / "README.md").write_text("no offset stated here\n")
    np.testing.assert_allclose(load_recording(seq, check=False).anchors.position(1), [2.0, 2.0, 1.0])
    (tmp_path / "data" / "README.md").write_text("adds (0, -0.05) m to the anchor positions\n")
    with pytest.raises(RecordingError, match="not three numbers"):
        load_recording(seq)


def _rcv_copy(tmp_path: Path) -> Path:
    return write_rcv_twr_mini(tmp_path / "seq")


def _edit_line(path: Path, lineno: int, col: int, value: str) -> None:
    lines = path.read_text().splitlines()
    cells = lines[lineno - 1].split(",")
    cells[col] = value
    lines[lineno - 1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def test_rcv_twr_malformed(tmp_path: Path) -> None:
    d = _rcv_copy(tmp_path)
    _edit_line(d / "anchor_3.csv", 5, 0, "2024-06-09 19:39:13.100000")
    with pytest.raises(RecordingError, match="time goes backwards") as info:
        load_recording(d)
    assert info.value.path == d / "anchor_3.csv" and info.value.line == 5 and info.value.field == "Time"

    d = _rcv_copy(tmp_path / "b")
    _edit_line(d / "gt.csv", 7, 0, "yesterday")
    with pytest.raises(RecordingError, match="expected a date-time") as info:
        load_recording(d)
    assert info.value.path == d / "gt.csv" and info.value.line == 7

    d = _rcv_copy(tmp_path / "c")
    shutil.copy(d / "anchor_4.csv", d / "anchor_7.csv")
    with pytest.raises(RecordingError, match=r"unknown anchor 7"):
        load_recording(d)

    d = _rcv_copy(tmp_path / "d")
    (d / "anchor.yaml").write_text((d / "anchor.yaml").read_text().replace("[2.0, 2.0, 1.0]", "[2.0, oops, 1.0]"))
    with pytest.raises(RecordingError, match="expected 3 numbers") as info:
        load_recording(d)
    assert info.value.line == 3 and info.value.field == "anchor1.position"

    d = _rcv_copy(tmp_path / "e")
    (d / "anchor.yaml").unlink()
    with pytest.raises(FileNotFoundError, match="anchor.yaml"):
        load_rcv_twr(d)


# ------------------------------------------------------------------------------------ shared data
@pytest.mark.skipif(not UTIL_FILES, reason=NO_DATA)
@pytest.mark.parametrize("path", UTIL_FILES, ids=lambda p: p.stem)
def test_shared_util_recordings_load(path: Path) -> None:
    f = load_recording(path, DATA / "util" / "anchors.csv")
    assert f.uwb.kind == KIND_TDOA and f.imu is None and f.meta["constellation"] == int(path.name[5])
    rows = int(f.meta["rows"])  # type: ignore[arg-type]
    assert 0.3 * rows < len(f.uwb) <= rows and sum(f.meta["dropped"].values()) < 100  # type: ignore[union-attr]
    e = f.uwb.value - f.uwb.true_value  # type: ignore[operator]
    core = e[np.abs(e) < 1.0]
    # LOS flights: median ~0, std ~0.09-0.12 m; const3 (NLOS) ~0.2 m (data README); TDoA3 files hold ~1%
    # gross outliers (+-127 m). A wrong sign, pair order, lever arm or anchor set would give metres.
    assert abs(np.median(core)) < 0.03 and core.std() < 0.25 and core.size > 0.97 * e.size
    assert 200 < len(f.uwb) / f.duration_s < 600


@pytest.mark.skipif(not RCV_DIRS, reason=NO_DATA)
@pytest.mark.parametrize("path", RCV_DIRS, ids=lambda p: p.name)
def test_shared_rcv_twr_recordings_load(path: Path) -> None:
    f = load_recording(path)
    assert f.uwb.kind == KIND_TWR and set(f.uwb.anchor_a.tolist()) == {1, 2, 3, 4}
    assert np.all(f.uwb.value > 0) and 15 < len(f.uwb) / f.duration_s < 30
    e = f.uwb.value - f.uwb.true_value  # type: ignore[operator]
    # these radios range long by 0.1-0.35 m (per-anchor median), with a few gross outliers
    assert 0.05 < np.median(e) < 0.45 and np.mean(np.abs(e) < 1.0) > 0.98


# ------------------------------------------------------------------------------------ through the device
@pytest.mark.skipif(not UTIL_FILES, reason=NO_DATA)
def test_real_util_flight_slice_replays_through_the_device(uwb_device) -> None:  # noqa: ANN001
    from harness.report.metrics import accuracy_summary
    from harness.stream.streamer import Pacing, Streamer
    flight = time_slice(load_recording(DATA / "util" / "const1" / "const1-trial1-tdoa2-extracted.csv"), 10.0, 20.0)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    assert cfg.mode == MODE_UWB_ONLY
    run = Streamer(uwb_device).run(flight, cfg, Pacing("windowed", 64))
    assert run.n_received == len(flight.uwb) > 4000
    acc = accuracy_summary(run, flight)
    # measured 0.097 m (z 0.093: the per-pair biases the bias network is meant to remove), xy 0.03 m
    assert acc.rmse < 0.15 and acc.rmse_xy < 0.08
    assert acc.accepted > 0.95 * len(flight.uwb)


def test_cli_replays_a_recording(uwb_firmware: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from harness.cli import main
    if not uwb_firmware.is_file():
        pytest.skip(f"firmware binary {uwb_firmware} not built (make firmware)")
    assert main(["run", "--recording", str(REDUCED), "--anchors", str(FIX / "anchors.csv"), "--stages", "outlier",
                 "--firmware", str(uwb_firmware)]) == 0
    out = capsys.readouterr().out
    assert "flight const1-fixture-tdoa2: 40 measurements, 40 results" in out and "position RMSE" in out
    assert main(["run", "--recording", str(FIX / "const1-bad-nan.csv"), "--firmware", str(uwb_firmware)]) == 2
    assert "line 12" in capsys.readouterr().err
    assert main(["run", "--recording", str(REDUCED), "--stages", "none", "--set", "std_tdoa=0.1", "--json",
                 "--firmware", str(uwb_firmware)]) == 0
    assert '"measurements": 40' in capsys.readouterr().out
    assert main(["run", "--recording", str(REDUCED), "--set", "std_tdao=0.1", "--firmware", str(uwb_firmware)]) == 2
    assert "expected FIELD=VALUE" in capsys.readouterr().err
