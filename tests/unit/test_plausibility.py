"""Recordings are checked before they are trusted: a file in the wrong units, with a broken anchor survey,
mostly gross errors or truth from another clock loads syntactically but is refused by `uwb-hil run` with
exit code 2, the file and the likely cause; `--force` replays it anyway. Every shared recording passes.

The recordings here are synthetic UTIL reduced CSVs written by `write_util` (exact TDoA values to a tag on
a circle inside the fixture constellation), then broken in one way each.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from harness import cli
from harness.flight.loaders import load_recording
from harness.flight.plausibility import ImplausibleRecording, findings
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir

FIX = Path(__file__).parents[1] / "fixtures" / "recordings"
DATA = shared_data_dir()
SHARED = (sorted((DATA / "util").glob("const*/*.csv")) + sorted((DATA / "rcv_twr").glob("sequence*"))
          if DATA.is_dir() else [])
ANCHORS = {0: (-3.0, -4.0, 0.2), 1: (-3.0, 4.0, 2.6), 2: (3.5, 3.5, 0.15), 3: (3.5, -3.7, 2.7),
           4: (-3.3, -3.9, 2.7), 5: (3.3, -3.6, 0.2), 6: (3.8, 3.6, 2.6), 7: (-2.7, 3.2, 0.15)}
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


def write_anchors(path: Path, anchors: dict[int, tuple[float, float, float]], scale: float = 1.0,
                  constellation_column: bool = True) -> Path:
    head = "constellation,anchor_id,x_m,y_m,z_m" if constellation_column else "anchor_id,x_m,y_m,z_m"
    rows = [(f"1,{a}," if constellation_column else f"{a},") + ",".join(f"{scale * v:.6f}" for v in p)
            for a, p in anchors.items()]
    path.write_text("\n".join([head, *rows]) + "\n")
    return path


def write_util(path: Path, *, seconds: float = 20.0, pose_scale: float = 1.0, time_scale: float = 1.0,
               pose_shift_s: float = 0.0, gross_share: float = 0.0, gap_s: float = 0.0) -> Path:
    """A reduced UTIL CSV (TDoA at 100 Hz round robin over the 8 anchors, poses at 100 Hz): exact values
    (the tag is the pose + the 0.0908 m lever arm the loader adds), then scaled / shifted / corrupted."""
    n = int(seconds * 100)
    t = np.arange(n) * 0.01
    pose = np.stack([1.5 * np.cos(0.3 * t), 1.5 * np.sin(0.3 * t), 1.0 + 0.2 * np.sin(0.5 * t)], axis=1)
    tag = pose + [0.0, 0.0, 0.0908]
    ids = np.array(sorted(ANCHORS))
    pos = np.array([ANCHORS[int(i)] for i in ids])
    a = ids[np.arange(n) % 8]
    b = ids[(np.arange(n) + 1) % 8]
    tdoa = np.linalg.norm(pos[b] - tag, axis=1) - np.linalg.norm(pos[a] - tag, axis=1)
    bad = np.random.default_rng(0).random(n) < gross_share
    t = t + np.where(np.arange(n) >= n // 2, gap_s, 0.0)      # the clock jumps half way (after the geometry)
    tdoa[bad] += 5.0
    lines = ["idA,idB,tdoa_meas,t_tdoa,pose_x,pose_y,pose_z,t_pose"]
    for k in range(n):
        p = pose[k] * pose_scale
        lines.append(f"{a[k]},{b[k]},{tdoa[k]:.9f},{(t[k] + 0.002) * time_scale:.6f},{p[0]:.9f},{p[1]:.9f},"
                     f"{p[2]:.9f},{(t[k] + pose_shift_s) * time_scale:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return path


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = cli.main(["run", *argv, "--stages", "outlier", "--json"])
    out = capsys.readouterr()
    return rc, out.out, out.err


BROKEN = {
    # name: (recording kwargs, anchors kwargs, expected phrase in the error)
    "anchors in mm": ({}, {"scale": 1000.0}, "anchors span 10.+ m .*looks like millimetres"),
    "poses in mm": ({"pose_scale": 1000.0}, {}, "poses are a median .* m from the anchors' centre.*looks like "
                                               "millimetres"),
    "times in ms": ({"time_scale": 1000.0}, {}, "times look like milliseconds"),
    "gross errors": ({"gross_share": 0.7}, {}, r"7\d % of the measurements differ from the ground truth"),
    "poses on another clock": ({"pose_shift_s": 15.0}, {}, "only 25 % of the measurements fall within the "
                                                         "ground-truth poses' time span"),
    # a realtime replay waited the pause out, silent (issue: "never hangs")
    "a jump of the clock": ({"gap_s": 100.0}, {}, "the UWB stream pauses for 100 s of its 120 s"),
}


@needs_fw
@pytest.mark.parametrize("case", sorted(BROKEN))
def test_implausible_recording_is_refused_with_the_cause_and_force_replays_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str) -> None:
    rec_kw, anc_kw, phrase = BROKEN[case]
    rec = write_util(tmp_path / "const1-flight.csv", **rec_kw)
    anchors = write_anchors(tmp_path / "anchors.csv", ANCHORS, **anc_kw)
    rc, out, err = _run(["--recording", str(rec), "--anchors", str(anchors)], capsys)
    assert rc == 2 and out == ""
    assert err.startswith("uwb-hil: error: ") and str(rec) in err and "--force" in err, err
    assert re.search(phrase, err), err
    assert "Traceback" not in err
    rc, out, err = _run(["--recording", str(rec), "--anchors", str(anchors), "--force"], capsys)
    assert rc != 2 or "implausible" not in err, err        # --force skips the check (the verdict may still fail)
    if rc == 0:
        assert json.loads(out)["measurements"] >= 500


@needs_fw
def test_the_clean_synthetic_recording_replays(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = write_util(tmp_path / "const1-flight.csv")
    rc, out, err = _run(["--recording", str(rec), "--anchors", str(write_anchors(tmp_path / "a.csv", ANCHORS))],
                        capsys)
    assert rc == 0, err
    assert json.loads(out)["accuracy"]["rmse"] < 0.1


@pytest.mark.parametrize("anchors, phrase", [
    ({k: (1.0, 2.0, 0.5) for k in ANCHORS}, "all 8 anchors lie within 0.000 m of each other"),
    ({**ANCHORS, 5: ANCHORS[4]}, "1 pair\\(s\\) of anchors at the same position 4-5: coincident anchors"),
    ({k: (float(k), 2.0 * k, 1.0) for k in ANCHORS}, "the anchors lie on one line"),
])
def test_degenerate_anchor_geometry_is_refused(tmp_path: Path, anchors: dict[int, tuple[float, float, float]],
                                               phrase: str) -> None:
    rec = write_util(tmp_path / "const1-flight.csv", seconds=2.0)
    with pytest.raises(ImplausibleRecording, match=phrase) as info:
        load_recording(rec, write_anchors(tmp_path / "anchors.csv", anchors))
    assert str(rec) in str(info.value)
    load_recording(rec, tmp_path / "anchors.csv", check=False)       # the format itself is fine


@pytest.mark.parametrize("recording", [FIX / "const1-fixture-tdoa2.csv", FIX / "const2-fixture-official.csv"])
def test_anchor_file_without_constellation_column_works_with_any_recording(tmp_path: Path,
                                                                           recording: Path) -> None:
    # the fixture constellations 1 and 2 differ by 0.1 m in z: write the one the recording was made with
    const = int(recording.name[5])
    rows = [line.split(",") for line in (FIX / "anchors.csv").read_text().splitlines()[1:]]
    anchors = {int(r[1]): tuple(float(v) for v in r[2:]) for r in rows if int(r[0]) == const}
    plain = write_anchors(tmp_path / "anchors.csv", anchors, constellation_column=False)  # type: ignore[arg-type]
    flight = load_recording(recording, plain)
    ref = load_recording(recording, FIX / "anchors.csv")
    assert np.allclose(flight.anchors.positions, ref.anchors.positions, atol=1e-6)
    assert np.allclose(flight.uwb.true_value, ref.uwb.true_value)
    assert load_recording(recording, plain, constellation=const).uwb.value.size == ref.uwb.value.size


def test_multi_constellation_hint_names_a_real_option(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = FIX / "const1-fixture-tdoa2.csv"
    unnamed = tmp_path / "flight.csv"
    unnamed.write_text(rec.read_text())
    assert cli.main(["run", "--recording", str(unnamed), "--anchors", str(FIX / "anchors.csv")]) == 2
    err = capsys.readouterr().err
    assert "--constellation N" in err and "constellation=N" not in err
    assert cli.build_parser().parse_args(["run", "--constellation", "2"]).constellation == 2


@pytest.mark.skipif(not SHARED, reason=f"shared data folder {DATA} is absent")
def test_every_shared_recording_is_plausible() -> None:
    for path in SHARED:
        assert findings(load_recording(path, check=False)) == [], path


def test_truth_on_another_clock_is_refused_in_a_native_file(tmp_path: Path) -> None:
    from dataclasses import replace

    from harness.flight.native import save_flight
    from harness.flight.scenarios import scenario_flight
    flight = scenario_flight("circle", mode="twr", duration_s=10.0, seed=1)
    assert findings(flight) == []
    late = replace(flight, truth=replace(flight.truth, t_us=flight.truth.t_us + 7_000_000))
    path = save_flight(late, tmp_path / "late.npz")
    with pytest.raises(ImplausibleRecording, match=r"poses cover 3\d % of the measurements' time span"):
        load_recording(path)


def test_figures_carry_the_imu_units_the_checks_judge() -> None:
    from dataclasses import replace

    from harness.flight.plausibility import figures
    from harness.flight.scenarios import scenario_flight
    flight = scenario_flight("circle", mode="twr", duration_s=10.0, seed=1)
    assert flight.imu is not None
    fig = figures(flight)
    assert 9.0 < fig["acc_median_mps2"] < 11.0 and 0.0 < fig["gyro_p99_rads"] < 2.0
    in_g = replace(flight, imu=replace(flight.imu, acc=flight.imu.acc / 9.81))
    assert abs(figures(in_g)["acc_median_mps2"] - fig["acc_median_mps2"] / 9.81) < 1e-9
    assert any("looks like g" in f for f in findings(in_g))
    assert "acc_median_mps2" not in figures(replace(flight, imu=None))
