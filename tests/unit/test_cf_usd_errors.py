"""Crazyflie uSD event logs, bad input: every refusal names the file and the byte offset; nothing half-loaded."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from harness.flight.formats.cf_usd import read_usd_log
from harness.flight.formats.cf_usd_flight import UsdOptions
from harness.flight.formats.crc_locate import candidate_offsets
from harness.flight.loaders import RecordingError, load_recording
from usd_writer import UsdWriter, hover_log, write_anchors


@pytest.fixture
def day(tmp_path: Path) -> Path:
    write_anchors(tmp_path / "anchor_0101.npz")
    return tmp_path


def _refused(path: Path, offset: int | None, *words: str, **kw: object) -> RecordingError:
    with pytest.raises(RecordingError) as err:
        load_recording(path, **kw)  # type: ignore[arg-type]
    exc = err.value
    text = str(exc)
    assert str(path) in text, text
    if offset is not None:
        assert exc.offset == offset and f"byte offset {offset}" in text, text
    for w in words:
        assert w in text, text
    return exc


@pytest.mark.parametrize("which", ["record", "header", "crc"])
def test_flipped_byte_names_its_offset(day: Path, which: str) -> None:
    w = hover_log()
    path = w.write(day / "0101-traj1")
    data = bytearray(path.read_bytes())
    at = {"record": w.offset_of(w.index_of("estTDOA", 7)) + 12, "header": 40, "crc": len(data) - 2}[which]
    data[at] ^= 0x24
    path.write_bytes(bytes(data))
    _refused(path, at, "CRC-32 mismatch", "--ignore-crc")
    if which == "record":     # a flipped value: loads with --ignore-crc, the mismatch kept as a warning
        flight = load_recording(path, usd=UsdOptions(ignore_crc=True))
        assert flight.meta["crc_ok"] is False
        assert any(f"byte offset {at}" in s and "CRC-32" in s for s in flight.meta["warnings"])  # type: ignore


def test_crc_locator_on_random_positions() -> None:
    rng = np.random.default_rng(3)
    msg = bytearray(rng.integers(0, 256, 200_000, dtype=np.uint8).tobytes())
    good = zlib.crc32(bytes(msg))
    for at in (0, 1, 99_999, 199_999):
        bad = bytearray(msg)
        bad[at] ^= int(rng.integers(1, 256))
        assert at in candidate_offsets(bytes(bad), good ^ zlib.crc32(bytes(bad)))
    assert candidate_offsets(bytes(msg), 0x00FF0000) == [200_002]   # only a byte of the CRC field differs


def test_truncated_record(day: Path) -> None:
    w = hover_log()
    body = w.body()
    last = w.offset_of(len(w.records) - 1)
    path = w.write(day / "0101-traj1", body=body[:-3])          # the logger stopped mid-record, CRC over it
    _refused(path, last, "truncated record", "needs")
    cut = day / "0101-traj2"                                    # a copy cut short: the CRC fails as well
    cut.write_bytes(w.write(day / "0101-full").read_bytes()[:-10])
    _refused(cut, None, "truncated record", "CRC does not match either")


def test_undeclared_event_id_in_records(day: Path) -> None:
    w = hover_log()
    body = bytearray(w.body())
    at = w.offset_of(w.index_of("estPose", 3))
    body[at:at + 2] = struct.pack("<H", 77)
    path = w.write(day / "0101-traj1", body=bytes(body))
    _refused(path, at, "undeclared event id 77", "estTDOA")


def test_unknown_event_type_listed_and_skipped(day: Path) -> None:
    w = hover_log()
    w.events["estFancy"] = (12, ["a(f)", "b(i)"])
    for k in range(5):
        w.add(1_000_500 + k * 1000, "estFancy", 1.5, -3)
    w.records.sort(key=lambda r: r[0])
    flight = load_recording(w.write(day / "0101-traj1"))
    assert flight.meta["ignored_events"] == {"estBarometer": 100, "estFancy": 5}
    assert flight.meta["warnings"] == ["unknown event type(s) skipped: estFancy (5 records)"]
    log = read_usd_log(day / "0101-traj1")
    assert log.events["estFancy"]["b"].tolist() == [-3] * 5


def test_no_uwb_events(day: Path) -> None:
    _refused(hover_log(tdoa=False).write(day / "0101-traj1"), None, "no UWB measurements", "estTDOA", "estDistance")


def test_no_pose(day: Path) -> None:
    exc = _refused(hover_log(pose=False).write(day / "0101-traj1"), None, "no ground truth", "no accuracy")
    assert "estPose" in str(exc)


def test_time_going_backwards(day: Path) -> None:
    w = hover_log()
    i = w.index_of("estTDOA", 10)
    t, ev, vals = w.records[i]
    w.records[i] = (t - 20_000, ev, vals)
    path = w.write(day / "0101-traj1")
    _refused(path, w.offset_of(i), "estTDOA time goes backwards")


@pytest.mark.parametrize("case", ["letter", "count", "version", "name", "magic"])
def test_bad_header(day: Path, case: str) -> None:
    w = hover_log(seconds=0.2)
    if case == "letter":
        w.events["estBarometer"] = (2, ["baro.asl(z)"])
        head = w.header()
        at = head.index(b"baro.asl(z)")
        _refused(w.write(day / "0101-traj1", body=head), at, "'name(T)'")
        return
    body = bytearray(w.body())
    at = {"count": 7, "version": 1, "name": 7, "magic": 0}[case]
    if case == "count":                             # more types than the header-only file holds
        body = bytearray(w.header())
        body[3:5] = struct.pack("<H", len(w.events) + 1)
        at = len(body)                              # where the missing type would start
    elif case == "version":
        body[1:3] = struct.pack("<H", 3)
    elif case == "name":
        body[8] = 0xFF                              # inside the first type's name: not ASCII
    else:
        body[0] = 0xBD
    path = w.write(day / "0101-traj1", body=bytes(body))
    if case == "magic":                             # not detected as a uSD log at all: not a text file either
        _refused(path, None, "not a text file")
        return
    words = {"count": ("runs beyond the file",), "version": ("unknown log version 3",), "name": ("not ASCII",)}
    _refused(path, at, *words[case])


def test_anchor_id_and_values_checked(day: Path) -> None:
    w = hover_log()
    i = w.index_of("estTDOA", 4)
    t, ev, (a, _, d) = w.records[i]
    w.records[i] = (t, ev, (a, 9, d))
    _refused(w.write(day / "0101-traj1"), w.offset_of(i), "names anchor 9")
    w = hover_log()
    i = w.index_of("estPose", 2)
    t, ev, v = w.records[i]
    w.records[i] = (t, ev, (float("nan"),) + v[1:])
    _refused(w.write(day / "0101-traj2"), w.offset_of(i), "non-finite value")


def test_no_anchor_file_beside_the_log(tmp_path: Path) -> None:
    path = hover_log().write(tmp_path / "0101-traj1")
    _refused(path, None, "anchor_<day>.npz", "--anchors")
    flight = load_recording(path, anchors=write_anchors(tmp_path / "elsewhere.npz"))
    assert len(flight.anchors.ids) == 8


def test_empty_log_header_only(day: Path) -> None:
    w = UsdWriter()
    _refused(w.write(day / "0101-traj1"), None, "no UWB measurements")


@pytest.mark.parametrize("kw, phrase", [({"acc_z": 9.81}, "median |acceleration| is 96.2 m/s^2"),
                                        ({"acc_z": 0.1}, "looks like g"),
                                        ({"gyro_z": 3000.0}, "looks like deg/s")])
def test_imu_in_the_wrong_units_is_implausible(day: Path, kw: dict[str, float], phrase: str) -> None:
    path = hover_log(**kw).write(day / "0101-traj1")       # type: ignore[arg-type]
    _refused(path, None, phrase, "--force")
    assert load_recording(path, check=False).has_imu
