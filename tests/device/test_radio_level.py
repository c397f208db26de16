"""LPS radio level end to end: RADIO frames through the firmware's TDoA engine and pipeline (emulator,
or the board/QEMU the plugin selects), the STATS radio counters, CLOCK replies against the simulator's
truth, malformed frames, recorded UTIL flights synthesised at radio level, the CLI's --radio."""

from __future__ import annotations

import json
from dataclasses import asdict
import subprocess
import sys

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.flight.loaders import load_recording
from harness.flight.radio import radio_level
from harness.flight.radio_replay import radio_from_recording
from harness.flight.scenarios import scenario_flight
from harness.report.metrics import accuracy_summary
from harness.report.radio import query_clocks, radio_summary
from harness.report.radio_streams import firmware_check
from harness.flight.run_config import config_for
from harness.paths import shared_data_dir
from harness.stream.streamer import OUTCOME_NO_MEAS, OUTCOME_RESULT, Pacing, Streamer
from harness.twin.tdoa_engine import MEASUREMENT, replay
from protocol import messages as m
from protocol._generated import DropReason

UTIL = shared_data_dir() / "util"


def _stats_delta(run) -> dict[str, int]:  # noqa: ANN001
    """The device's STATS counters over one run: after minus before (the setup's STATS)."""
    assert run.stats is not None and run.stats_start is not None
    before, after = asdict(run.stats_start), asdict(run.stats)
    return {k: int(after[k]) - int(before[k]) for k in after if isinstance(after[k], int)}


def _twin(flight):  # noqa: ANN001, ANN202
    r = flight.radio
    return replay(r.t_us.tolist(), [int(v) for v in r.rx_ts], [int(v) for v in r.src_addr],
                  [bytes(r.payload[k, :int(r.length[k])]) for k in range(len(r))])


@pytest.mark.parametrize("protocol", ["tdoa2", "tdoa3"])
def test_radio_flight_through_the_firmware(uwb_device, protocol: str) -> None:  # noqa: ANN001
    base = scenario_flight("circle", mode="tdoa", duration_s=6.0, seed=3)
    flight = radio_level(base, protocol, seed=3, loss=0.1)
    streamer = Streamer(uwb_device)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    run = streamer.run(flight, cfg, Pacing("windowed", 64), radio=True)
    _, twin = _twin(flight)
    out = run.results["outcome"]
    # the firmware forms exactly the twin's measurements, and says why for every other packet
    assert (out == OUTCOME_RESULT).tolist() == [rc == MEASUREMENT for rc, _ in twin]
    drop_codes = run.results["error_code"][out == OUTCOME_NO_MEAS].tolist()
    assert drop_codes == [rc for rc, _ in twin if rc != MEASUREMENT]
    # the board's counters are cumulative (a board on the bench is not restarted between tests): deltas
    s = _stats_delta(run)
    assert s["radio_packets"] == len(flight.radio) and s["radio_meas"] == run.n_received
    assert (s["radio_no_reference"] + s["radio_clock"] + s["radio_expired"] + s["radio_malformed"]
            + s["radio_unknown_type"] + s["radio_no_position"]) == int(np.count_nonzero(out == OUTCOME_NO_MEAS))
    summary = radio_summary(run, flight, query_clocks(streamer, flight))
    assert summary["measurements"] == run.n_received > 0.7 * len(flight.radio)  # type: ignore[arg-type]
    assert summary["max_skew_error_ppm"] < 0.05
    assert all(c["known"] and c["bucket"] > 0 for c in summary["clock"].values())
    assert accuracy_summary(run, flight).rmse < 0.15


def test_radio_level_rmse_within_5_percent_of_measurement_level(uwb_device) -> None:  # noqa: ANN001
    """The same simulated flight (same pairs, times, link errors) as differences and as packets, 60 s as in
    docs/radio.md (`python -m harness.radio_compare --seeds 6 --duration 60`: largest change 1.67 %). The
    comparison holds only if the firmware formed the twin's measurements: a binary built before the
    TDoA3 reference changed (rotating, the twin youngest) flew other pairs and moved the RMSE by up to
    6.27 % (docs/radio.md)."""
    base = scenario_flight("circle", mode="tdoa", duration_s=60.0, seed=2)
    streamer = Streamer(uwb_device)
    for protocol in ("tdoa2", "tdoa3"):
        flight = radio_level(base, protocol, seed=2)
        cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
        meas = accuracy_summary(streamer.run(flight, cfg, Pacing("windowed", 64)), flight).rmse
        run = streamer.run(flight, cfg, Pacing("windowed", 64), radio=True)
        assert firmware_check(run, flight).ok
        radio = accuracy_summary(run, flight).rmse
        assert abs(radio - meas) / meas < 0.05, (protocol, meas, radio)


def _radio_msg(payload: bytes, rx_ts: int = 1000, src: int = 0xBCCF000000000001, t_us: int = 10,
               length: int | None = None, pad: bytes | None = None) -> m.Radio:
    body = (payload + (pad or b"")).ljust(128, b"\0")
    return m.Radio(t_us=t_us, rx_ts=rx_ts, src_addr=src, length=len(payload) if length is None else length,
                   payload=body)


def test_malformed_radio_frames_are_dropped_with_their_reason(uwb_device) -> None:  # noqa: ANN001
    """Needs a TDoA engine that knows no anchor yet (the first well-formed packet has no clock): on a board
    that ran other tests before, a CONFIG with reset (the protocol's documented way) forgets them."""
    ch = uwb_device.channel
    ch.configure(EstimatorConfig(), None, reset=True, timeout=5.0)
    tdoa3 = bytes([0x30, 1, 0, 0, 0, 0, 0])
    cases = [
        (_radio_msg(tdoa3, rx_ts=1 << 40), DropReason.MALFORMED),        # beyond 40 bits
        (_radio_msg(tdoa3, pad=b"\x01"), DropReason.MALFORMED),          # bytes after `length`
        (_radio_msg(tdoa3, length=129), DropReason.MALFORMED),
        (_radio_msg(b"\x77" * 10), DropReason.UNKNOWN_TYPE),
        (_radio_msg(bytes([0x22]) * 57, src=0xBCCF000000000009), DropReason.MALFORMED),  # TDoA2 id > 7
        (_radio_msg(tdoa3), DropReason.CLOCK_UNRELIABLE),                # well formed: first packet
    ]
    for k, (msg, reason) in enumerate(cases):
        ch.send(msg)
        got = ch.expect(lambda f: isinstance(f.msg, m.RadioDrop), 5.0, "RADIO_DROP").msg
        assert got.reason == reason, k
    ch.send(m.ClockReq(anchor_id=200))
    clock = ch.expect(lambda f: isinstance(f.msg, m.Clock), 5.0, "CLOCK").msg
    assert clock.anchor_id == 200 and clock.known == 0
    ch.send(m.ClockReq(anchor_id=1))
    clock = ch.expect(lambda f: isinstance(f.msg, m.Clock), 5.0, "CLOCK").msg
    assert clock.known == 1 and clock.packets == 1 and clock.bucket == 0


@pytest.mark.skipif(not UTIL.is_dir(), reason=f"{UTIL} missing")
@pytest.mark.parametrize("name,protocol", [("const1/const1-trial1-tdoa2-extracted.csv", "tdoa2"),
                                           ("const1/const1-trial2-tdoa3-extracted.csv", "tdoa3")])
def test_recorded_util_flight_reproduced_at_radio_level(name: str, protocol: str) -> None:
    """Ideal clocks: the engine forms every recorded difference, with its anchor pair, within 1 mm."""
    flight = load_recording(UTIL / name, anchors=UTIL / "anchors.csv")
    rflight = radio_from_recording(flight, protocol)
    _, out = _twin(rflight)
    meas = [mm for rc, mm in out if rc == MEASUREMENT]
    assert len(meas) == len(flight.uwb)
    assert [(mm.anchor_a, mm.anchor_b) for mm in meas] == list(zip(flight.uwb.anchor_a.tolist(),
                                                                    flight.uwb.anchor_b.tolist()))
    err = np.array([mm.diff for mm in meas]) - flight.uwb.value
    assert np.max(np.abs(err)) < 1e-3
    assert np.any(np.diff(rflight.radio.rx_ts.astype(np.int64)) < 0)   # crosses the 40-bit wrap  # type: ignore[union-attr]


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "harness.cli", *args], capture_output=True, text=True, timeout=300)


def test_cli_run_radio_json_and_usage_error() -> None:
    r = _cli("run", "--radio", "tdoa3", "--mode", "tdoa", "--duration", "4", "--stages", "outlier", "--json")
    assert r.returncode == 0, r.stderr
    radio = json.loads(r.stdout)["radio"]
    assert radio["protocol"] == "tdoa3" and radio["packets"] > 1000 and radio["max_skew_error_ppm"] < 0.05
    assert radio["measurements"] + radio["no_measurement"] == radio["packets"]
    assert radio["device_counters"]["radio_meas"] == radio["measurements"]
    bad = _cli("run", "--radio", "tdoa2", "--mode", "twr", "--duration", "4")
    assert bad.returncode == 2 and "uwb-hil: error: --radio" in bad.stderr


def _write_trace(path, radio, header: bool = True) -> None:  # noqa: ANN001
    lines = ["# captured anchor packets", "t_rx_ticks,sender,packet_hex"] if header else []
    for k in range(len(radio)):
        lines.append(f"{int(radio.rx_ts[k])},{int(radio.src_addr[k]) & 0xFF},"
                     f"{bytes(radio.payload[k, :int(radio.length[k])]).hex()}")
    path.write_text("\n".join(lines) + "\n")


def test_radio_trace_replays_recorded_packets(tmp_path) -> None:  # noqa: ANN001
    """--radio-trace: the packets of a simulated flight, written as a trace, replayed to the firmware form
    as many measurements as the engine twin forms from them."""
    from harness.flight.radio_trace import load_radio_trace
    base = scenario_flight("circle", mode="tdoa", duration_s=4.0, seed=1)
    flight = radio_level(base, "tdoa3", seed=1)
    trace = tmp_path / "trace.csv"
    _write_trace(trace, flight.radio)
    loaded = load_radio_trace(trace)
    assert len(loaded) == len(flight.radio) and np.array_equal(loaded.rx_ts, flight.radio.rx_ts)
    assert np.all(np.diff(loaded.t_us) >= 0)
    r = _cli("run", "--mode", "tdoa", "--duration", "4", "--radio-trace", str(trace), "--stages", "outlier", "--json")
    assert r.returncode == 0, r.stderr
    radio = json.loads(r.stdout)["radio"]
    assert radio["protocol"] == "tdoa3" and radio["packets"] == len(flight.radio)
    assert radio["measurements"] > 0.9 * len(flight.uwb)


@pytest.mark.parametrize("line,reason", [("12,3", "expected 3 columns"), ("x,3,3000", "t_rx_ticks 'x'"),
                                         ("12,3,30zz", "not hexadecimal"), ("12,3,4100", "neither TDoA2"),
                                         (f"{1 << 40},3,3000", "outside")])
def test_malformed_radio_trace_exits_2_naming_the_line(tmp_path, line: str, reason: str) -> None:  # noqa: ANN001
    trace = tmp_path / "bad.csv"
    trace.write_text("t_rx_ticks,sender,packet_hex\n100,1,30000000000000\n" + line + "\n")
    r = _cli("run", "--mode", "tdoa", "--duration", "4", "--radio-trace", str(trace))
    assert r.returncode == 2 and f"{trace}:3: " in r.stderr and reason in r.stderr, r.stderr


def test_radio_trace_that_is_a_directory_or_missing_is_named_as_such(tmp_path) -> None:  # noqa: ANN001
    from harness.flight.radio_trace import RadioTraceError, load_radio_trace
    with pytest.raises(RadioTraceError, match="is a directory, not a radio trace file"):
        load_radio_trace(tmp_path)
    with pytest.raises(RadioTraceError, match="no such file"):
        load_radio_trace(tmp_path / "absent.csv")
