"""The native recording format (.npz): exact round trips of synthetic, simulated and loaded flights, refusal
of damaged or foreign files, the inspect command (summary and conversion) and time slices."""

from __future__ import annotations

import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.flight.loaders import RecordingError, load_flight, load_recording, save_flight, time_slice
from harness.flight.data import KIND_TWR, Anchors, Flight, ImuStream, Truth, UwbStream
from rcv_twr_mini import write_rcv_twr_mini

FIX = Path(__file__).parents[1] / "fixtures" / "recordings"
REDUCED = FIX / "const1-fixture-tdoa2.csv"
OFFICIAL = FIX / "const2-fixture-official.csv"


@pytest.fixture(scope="module")
def rcv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rcv_twr_mini(tmp_path_factory.mktemp("rcv") / "rcv_twr_mini")


def _synthetic_flight() -> Flight:
    rng = np.random.default_rng(3)
    n, k, m = 50, 30, 200
    q = rng.normal(size=(k, 4))
    return Flight(
        name="synthetic",
        anchors=Anchors(ids=np.array([0, 3, 5]), positions=rng.normal(size=(3, 3)),
                        orientations=np.array([[1.0, 0, 0, 0]] * 3)),
        uwb=UwbStream(kind=KIND_TWR, t_us=np.sort(rng.integers(0, 10**6, n)).astype(np.int64),
                      anchor_a=rng.choice([0, 3, 5], n), anchor_b=np.full(n, -1), value=rng.normal(size=n),
                      true_value=rng.normal(size=n)),
        truth=Truth(t_us=np.arange(k, dtype=np.int64) * 40_000, pos=rng.normal(size=(k, 3)),
                    quat=q / np.linalg.norm(q, axis=1, keepdims=True), vel=rng.normal(size=(k, 3))),
        imu=ImuStream(t_us=np.arange(m, dtype=np.int64) * 5000, acc=rng.normal(size=(m, 3)),
                      gyro=rng.normal(size=(m, 3))),
        meta={"seed": 3, "noise": "gaussian", "std": 0.1, "nested": {"a": [1, 2.5, None], "b": True}},
    )


def _assert_same(a: Flight, b: Flight) -> None:
    assert a.name == b.name and a.meta == b.meta and a.uwb.kind == b.uwb.kind
    for part in ("anchors", "uwb", "truth", "imu"):
        pa, pb = getattr(a, part), getattr(b, part)
        assert (pa is None) == (pb is None), part
        if pa is None:
            continue
        for name, va in vars(pa).items():
            vb = getattr(pb, name)
            if isinstance(va, np.ndarray) or isinstance(vb, np.ndarray):
                assert va is not None and vb is not None, f"{part}.{name}"
                assert va.dtype == vb.dtype and va.shape == vb.shape, f"{part}.{name}"
                assert va.tobytes() == vb.tobytes(), f"{part}.{name}"   # bit for bit
            else:
                assert va == vb, f"{part}.{name}"


def _simulated_flight() -> Flight:
    from harness.flight.scenarios import scenario_flight
    return scenario_flight("circle", mode="tdoa", duration_s=3.0, seed=2, noise="realistic")


@pytest.mark.parametrize("make", [lambda rcv: _synthetic_flight(), lambda rcv: _simulated_flight(),
                                  lambda rcv: load_recording(REDUCED), lambda rcv: load_recording(OFFICIAL),
                                  load_recording],
                         ids=["synthetic", "simulator", "util8", "util27", "rcv"])
def test_native_round_trip_is_exact(tmp_path: Path, rcv: Path, make) -> None:  # noqa: ANN001
    flight = make(rcv)
    path = save_flight(flight, tmp_path / "flight.npz")
    _assert_same(flight, load_flight(path))
    _assert_same(flight, load_recording(path, check=False))  # dispatch by content (the synthetic flight is
                                                             # random arrays: a format test, not a flight)
    with np.load(path, allow_pickle=False) as z:             # plain arrays, no pickles
        assert "flight_json" in z.files


def test_native_format_refuses_bad_files(tmp_path: Path) -> None:
    path = save_flight(_synthetic_flight(), tmp_path / "f.npz")
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(RecordingError, match="cut.npz"):
        load_flight(cut)
    survey = tmp_path / "anchor_const1.npz"
    np.savez(survey, an_pos=np.zeros((8, 3)), an_quat=np.tile([0, 0, 0, 1.0], (8, 1)))
    with pytest.raises(RecordingError, match="anchor survey"):
        load_recording(survey)
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    with np.load(path, allow_pickle=False) as z:
        header = str(z["flight_json"])
    bad = dict(members)
    del bad["uwb_value.npy"]
    _write_zip(tmp_path / "missing.npz", bad)
    with pytest.raises(RecordingError, match="required member missing") as info:
        load_flight(tmp_path / "missing.npz")
    assert info.value.field == "uwb_value"
    newer = np.lib.format
    import io
    buf = io.BytesIO()
    newer.write_array(buf, np.array(header.replace('"version": 1', '"version": 99')))
    bad = dict(members, **{"flight_json.npy": buf.getvalue()})
    _write_zip(tmp_path / "v99.npz", bad)
    with pytest.raises(RecordingError, match="unsupported format version 99"):
        load_flight(tmp_path / "v99.npz")
    texts = io.BytesIO()                                   # text where numbers belong: named (was exit 4)
    newer.write_array(texts, np.array(["x"] * 3))
    _write_zip(tmp_path / "text.npz", dict(members, **{"uwb_value.npy": texts.getvalue()}))
    with pytest.raises(RecordingError, match="expected numbers, got dtype <U1") as info:
        load_flight(tmp_path / "text.npz")
    assert info.value.field == "uwb_value"
    with pytest.raises(RecordingError, match="meta cannot be stored"):
        save_flight(replace(_synthetic_flight(), meta={"x": object()}), tmp_path / "g.npz")
    assert not (tmp_path / "g.npz").exists() and not (tmp_path / "g.npz.tmp").exists()


def _write_zip(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)


def test_inspect_command_summarises_and_converts(tmp_path: Path, rcv: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from harness.flight.loaders import error_summary, main
    out = tmp_path / "rcv.npz"
    assert main([str(rcv), "--save", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rcv_twr-rcv_twr_mini: 27 TWR measurements" in text and "nonpositive_range_anchor_2" in text
    _assert_same(load_recording(rcv), load_flight(out))
    s = error_summary(load_recording(rcv))
    assert s["n"] == 27 and s["gross"] == 0 and abs(s["median"]) <= 0.005  # type: ignore[operator]
    assert [g["group"] for g in s["groups"]] == ["1", "2", "3", "4"]  # type: ignore[index]
    pairs = error_summary(load_recording(REDUCED))["groups"]
    assert [g["group"] for g in pairs][:2] == ["0-1", "1-2"] and all(g["std"] < 1e-5 for g in pairs)  # type: ignore
    assert main([str(FIX / "const1-bad-nan.csv")]) == 2
    assert "line 12" in capsys.readouterr().err


def test_time_slice() -> None:
    f = load_recording(REDUCED)
    s = time_slice(f, 0.02, 0.05)
    assert s.uwb.t_us[0] >= f.uwb.t_us[0] + 20_000 and s.uwb.t_us[-1] < f.uwb.t_us[0] + 50_000
    assert s.truth.t_us[0] <= s.uwb.t_us[0] and s.truth.t_us[-1] >= s.uwb.t_us[-1]
    s.validate()
