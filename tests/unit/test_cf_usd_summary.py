"""What a uSD log holds without decoding it (harness/flight/formats/cf_usd_summary.py), scanned once per file
identity, and the calibrated lever arms fitted once per process (recipes.cf_usd_lever_arms)."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

from harness.flight.formats import cf_usd_summary
from harness.flight.formats.cf_usd import read_usd_log
from harness.flight.formats.cf_usd_summary import file_stamp, usd_summary
from harness.flight.loaders import RecordingError
from usd_writer import EVENTS, hover_log, write_anchors


def _counting_scans(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Every record walk the summary makes, by path."""
    walked: list[Path] = []
    real = cf_usd_summary.index_records

    def counting(data: bytes, path: Path):  # type: ignore[no-untyped-def]
        walked.append(path)
        return real(data, path)
    monkeypatch.setattr(cf_usd_summary, "index_records", counting)
    return walked


@pytest.mark.parametrize("version", [1, 2])
def test_fields_are_the_logs_counts_and_span(tmp_path: Path, version: int) -> None:
    w = hover_log(version=version, seconds=1.5, tof_mm=800)
    path = w.write(tmp_path / "0101-traj1")
    s = usd_summary(path)
    written = Counter(event for _, event, _ in w.records)
    assert dict(s.counts) == {name: written[name] for name in EVENTS}          # every declared type, in order
    assert [name for name, _ in s.counts] == list(EVENTS)
    assert s.count("estTDOA") == 300 and s.count("estTOF") == 38 and s.count("estNothing") == 0
    assert s.has_imu and s.has_tof_readings and s.uwb == "tdoa" and s.crc_ok
    assert (s.version, s.size, s.path) == (version, path.stat().st_size, path.resolve())
    times = [t for t, _, _ in w.records]
    tick = 1000 if version == 1 else 1
    assert (s.t_first_us, s.t_last_us) == (min(times) // tick * tick, max(times) // tick * tick)
    assert s.duration_s == pytest.approx((s.t_last_us - s.t_first_us) * 1e-6) and 1.49 < s.duration_s < 1.5
    log = read_usd_log(path)                    # the same counts as a full decode
    assert dict(s.counts) == {et.name: log.count(et.name) for et in log.types.values()}


def test_declared_but_empty_streams(tmp_path: Path) -> None:
    """estTOF declared with no readings (as the 0426 logs), TWR only, no IMU, no UWB."""
    twr = usd_summary(hover_log(tdoa=False, twr=True).write(tmp_path / "twr"))
    assert twr.uwb == "twr" and not twr.has_tof_readings and twr.count("estTOF") == 0 and twr.has_imu
    bare = hover_log(tdoa=False, extra=False)
    bare.records = [r for r in bare.records if r[1] == "estPose"]
    s = usd_summary(bare.write(tmp_path / "pose-only"))
    assert s.uwb is None and not s.has_imu and not s.has_tof_readings and s.count("estPose") == 200
    empty = hover_log()
    empty.records = []
    e = usd_summary(empty.write(tmp_path / "header-only"))
    assert e.t_first_us is None and e.duration_s == 0.0 and all(n == 0 for _, n in e.counts)


def test_a_crc_mismatch_is_noted_not_refused(tmp_path: Path) -> None:
    """As the plan read it before (ignore_crc): a flipped payload byte still walks, crc_ok says it."""
    w = hover_log(tof_mm=700)
    path = w.write(tmp_path / "flipped")
    data = bytearray(path.read_bytes())
    data[w.offset_of(w.index_of("estTOF")) + 2 + 8] ^= 0x01        # the first range's low byte
    path.write_bytes(bytes(data))
    s = usd_summary(path)
    assert not s.crc_ok and s.has_tof_readings


def test_scanned_once_per_file_identity(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    walked = _counting_scans(monkeypatch)
    path = hover_log().write(tmp_path / "log")
    first = usd_summary(path)
    assert usd_summary(path) is first
    assert usd_summary(str(path)) is first                                     # the same file, spelt otherwise
    monkeypatch.chdir(tmp_path)
    assert usd_summary(Path("log")) is first and usd_summary(Path("../") / tmp_path.name / "log") is first
    assert walked == [path.resolve()]


def test_a_changed_file_is_scanned_anew(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    walked = _counting_scans(monkeypatch)
    path = hover_log().write(tmp_path / "log")
    before = usd_summary(path)
    hover_log(tof_mm=650).write(path)                                          # new size
    after = usd_summary(path)
    assert not before.has_tof_readings and after.has_tof_readings and after.size > before.size
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))            # same size, new mtime
    assert usd_summary(path) is not after and usd_summary(path) == after
    assert len(walked) == 3
    assert file_stamp(path) == (str(path.resolve()), st.st_size, st.st_mtime_ns + 1_000_000)


def test_a_bad_file_raises_the_readers_error_naming_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    walked = _counting_scans(monkeypatch)
    w = hover_log()
    path = w.write(tmp_path / "bad")
    data = path.read_bytes()
    path.write_bytes(data[:w.offset_of(5) + 3])                                 # cut inside a record, no CRC
    for _ in range(2):                                                          # a refusal is not cached
        with pytest.raises(RecordingError) as err:
            usd_summary(path)
        assert str(path) in str(err.value) and err.value.path == path and err.value.offset is not None
    with pytest.raises(RecordingError) as full:
        read_usd_log(path, ignore_crc=True)
    assert str(err.value) == str(full.value)                                    # the reader's own reason
    assert len(walked) == 2
    path.write_bytes(b"PK\x03\x04 not a log at all")
    with pytest.raises(RecordingError, match="not a Crazyflie uSD event log") as magic:
        usd_summary(path)
    assert str(path) in str(magic.value)
    with pytest.raises(FileNotFoundError):
        usd_summary(tmp_path / "missing")


def _usd_day(data: Path) -> list[Path]:
    """Two 0425 training flights, one evaluation flight and their anchors under data/cf_usd/0425."""
    from harness.biasnet.recipes import CF_USD_EVAL, CF_USD_LOS
    paths = [data / CF_USD_LOS[0], data / CF_USD_LOS[1], data / CF_USD_EVAL[0]]
    paths[0].parent.mkdir(parents=True)
    write_anchors(paths[0].parent / "anchor_0425.npz")
    for k, p in enumerate(paths):
        hover_log(seconds=1.0 + 0.5 * k).write(p)
    return paths


def test_lever_arms_fitted_once_per_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import harness.flight.loaders as loaders
    from harness.biasnet.recipes import cf_usd_lever_arms
    train1, train2, held = _usd_day(tmp_path)
    loaded: list[str] = []
    real = loaders.load_recordings

    def counting(paths, *args, **kw):  # type: ignore[no-untyped-def]
        loaded.extend(Path(p).name for p in paths)
        return real(paths, *args, **kw)
    monkeypatch.setattr(loaders, "load_recordings", counting)
    first = cf_usd_lever_arms(tmp_path)
    assert set(first) == {train1.name, train2.name, held.name} and loaded == [train1.name, train2.name]
    assert len({first[n] for n in first}) == 1 and all(len(v) == 3 for v in first.values())
    first[held.name] = (9.0, 9.0, 9.0)                                          # a caller's dict is its own
    second = cf_usd_lever_arms(tmp_path)
    assert second[held.name] == second[train1.name] and len(loaded) == 2
    hover_log(seconds=1.2).write(train2)                                        # a training log changed
    third = cf_usd_lever_arms(tmp_path)
    assert len(loaded) == 4 and set(third) == set(second)
    anchors = train1.parent / "anchor_0425.npz"
    st = anchors.stat()
    os.utime(anchors, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))          # the anchors changed
    cf_usd_lever_arms(tmp_path)
    assert len(loaded) == 6
