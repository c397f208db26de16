"""Link faults and bad input: the CRC rejects corrupted frames, parsers resynchronise, the device's STATS
and the fault-injecting link agree on what was lost, every lost measurement is reported as LOST, the
estimate stays finite, and bad CONFIG values are refused without touching the running configuration.

Device tests use a fresh host firmware per test (STATS counts since power-up).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.device.host import HostDevice
from harness.flight.scenarios import scenario_flight
from harness.link.faulty import FaultRates, FaultyLink, SeqUnwrap, unwrap_seqs
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE
from protocol.batch import encode_rows
from harness.stream.streamer import OUTCOME_LOST, OUTCOME_RESULT, Pacing, Streamer
from protocol import encode_frame
from protocol import messages as m
from protocol.framing import FrameDecoder

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")

FIELDS_COMPARED = ["status", "innovation", "innovation_var", "bias", "d_max", "px", "py", "pz", "vx", "vy", "vz",
                   "var_x", "var_y", "var_z"]


@pytest.fixture
def device(tmp_path: Path) -> Iterator[HostDevice]:
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        yield dev


# ------------------------------------------------------------------------------- CRC, Python side
def _twr_rows(n: int, rng: np.random.Generator) -> np.ndarray:
    cols = {"t_us": rng.integers(0, 2**40, n), "anchor_id": rng.integers(0, 16, n),
            "range": rng.uniform(0.1, 20.0, n).astype(np.float32)}
    return encode_rows(m.Twr, cols, np.arange(n))      # (n, L + 2) incl. delimiter


def test_crc_rejects_a_million_bit_flipped_frames() -> None:
    """10^6 frames with 1..8 flipped bits (same length): the batch decoder accepts none."""
    from protocol.batch import decode_rows
    rng = np.random.default_rng(8)
    n = 1_000_000
    rows = _twr_rows(n, rng)[:, :-1].copy()            # COBS bytes without the delimiter
    width = rows.shape[1]
    flips = rng.integers(1, 9, n)
    for k in range(1, 9):
        sel = np.nonzero(flips >= k)[0]
        col = rng.integers(0, width, len(sel))
        rows[sel, col] ^= (1 << rng.integers(0, 8, len(sel))).astype(np.uint8)
    changed = np.any(rows != _twr_rows(n, np.random.default_rng(8))[:, :-1], axis=1)
    _, valid = decode_rows(m.Twr, rows[changed])
    assert changed.sum() > 0.99 * n                      # a double flip of the same bit cancels out
    assert int(valid.sum()) == 0


def test_crc_rejects_length_changing_corruptions() -> None:
    """2.5 x 10^5 frames truncated, shortened (dropped bytes) or lengthened (inserted bytes), as one byte
    stream through the scalar FrameDecoder: no frame is accepted, and every corrupted frame is counted."""
    rng = np.random.default_rng(9)
    n = 250_000
    rows = _twr_rows(n, rng)
    width = rows.shape[1] - 1
    kind = rng.integers(0, 3, n)
    pieces: list[bytes] = []
    for r, k, cut, pos, val in zip(rows.tolist(), kind.tolist(), rng.integers(1, width, n).tolist(),
                                   rng.integers(0, width, n).tolist(), rng.integers(1, 256, n).tolist()):
        enc = bytes(r[:-1])
        if k == 0:
            enc = enc[:cut]                                  # truncated
        elif k == 1:
            enc = enc[:pos] + enc[pos + 1:]                  # one byte dropped
        else:
            enc = enc[:pos] + bytes([val]) + enc[pos:]       # one non-zero byte inserted
        pieces.append(enc)
    dec = FrameDecoder()
    assert dec.feed(b"\x00".join(pieces) + b"\x00") == []
    assert dec.frames_ok == 0
    assert dec.errors.total() == n


# ------------------------------------------------------------------------------ resynchronisation
def test_device_resynchronises_after_garbage_and_oversize(device: HostDevice) -> None:
    rng = np.random.default_rng(3)
    ch = device.channel
    bursts = [rng.integers(1, 256, int(k), dtype=np.uint8).tobytes() for k in (1, 7, 250, 251, 252, 600, 5000)]
    stats0 = ch.stats()
    for burst in bursts:
        # garbage directly followed by a frame: that frame is lost with the garbage; the next one gets through
        device.link.write(burst + encode_frame(m.Hello(nonce=1), 999) + encode_frame(m.Hello(nonce=7), 1000))
        reply = ch.expect(lambda f: isinstance(f.msg, m.HelloReply), 5.0, "HELLO after garbage")
        assert reply.msg.nonce == 7
        assert ch.recv(0.05) is None                   # and nothing for the swallowed HELLO
    stats = ch.stats()
    bad = (stats.crc_errors - stats0.crc_errors) + (stats.framing_errors - stats0.framing_errors)
    assert bad == len(bursts)
    assert stats.frames_ok - stats0.frames_ok == len(bursts) + 1   # the second HELLOs + this STATS_REQ


# ----------------------------------------------------------------------------- faults on the link
def _flight(seconds: float = 8.0, mode: str = "twr", seed: int = 5):  # noqa: ANN202
    return scenario_flight("circle", mode=mode, duration_s=seconds, seed=seed, noise="gaussian", noise_std=0.05)


def _run_faulty(device: HostDevice, flight, tx: FaultRates, rx: FaultRates, seed: int,  # noqa: ANN001
                results_path: Path | None = None, window: int = 32):  # noqa: ANN202
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    stats0 = device.channel.stats(timeout=2.0)
    link = FaultyLink(device.link, tx=tx, rx=rx, seed=seed)
    with device.channel.through(link) as channel:      # the same session (seqs go on) over a faulty link
        run = Streamer(channel, timeout_s=1.0).run(flight, cfg, Pacing("windowed", window),
                                                   results_path=results_path)
    return run, link, stats0


def _delta(after: m.Stats, before: m.Stats) -> dict[str, int]:
    return {k: getattr(after, k) - getattr(before, k) for k, _ in m.Stats.FIELDS}


def test_tx_faults_are_accounted_by_device_and_results(device: HostDevice, tmp_path: Path) -> None:
    flight = _flight()
    rates = FaultRates(bit_flip=2e-4, drop_byte=2e-4, drop_frame=0.01, duplicate_frame=0.01,
                       truncate_frame=0.005, garbage=0.005, garbage_max=40)
    path = tmp_path / "faulty.jsonl"
    run, link, stats0 = _run_faulty(device, flight, rates, FaultRates(), seed=21, results_path=path)
    tx = link.tx_log
    c = tx.counts
    for what in ("frames_with_flipped_bits", "frames_with_dropped_bytes", "dropped_frames", "duplicated_frames",
                 "truncated_frames", "garbage_bursts"):
        assert c[what] > 3, f"the test should inject some {what}: {dict(c)}"
    d = _delta(run.stats, stats0)

    # 1. the device's parser and the link's shadow parser saw the same bad frames
    assert d["crc_errors"] == tx.delivered.errors.crc_errors
    assert d["framing_errors"] == tx.delivered.errors.framing_errors
    assert d["unknown_types"] == d["bad_lengths"] == 0          # no corrupted frame got past the CRC
    assert d["frames_ok"] == tx.delivered.frames_ok              # data + setup + the final STATS_REQ
    # 2. frames that never arrived intact are the device's seq gaps (duplicates are not gaps)
    lost = tx.lost_seqs
    assert d["seq_gaps"] == len(lost) > 0
    # 3. every measurement ends with an outcome; the LOST ones are exactly the measurements lost on the way
    res = run.results
    meas_seq = unwrap_seqs(res["meas_seq"])
    lost_meas = {int(s) for s in meas_seq} & lost
    assert set(meas_seq[res["outcome"] == OUTCOME_LOST].tolist()) == lost_meas
    assert int(np.count_nonzero(res["outcome"] == OUTCOME_RESULT)) == len(res) - len(lost_meas)
    # the device answered each intact copy (duplicates twice); the host kept one answer per measurement
    copies = sum(tx.intact_seqs[int(s)] for s in meas_seq)
    assert d["twr_meas"] == copies and d["results"] + d["dropped_meas"] == copies
    # 4. the estimate stays finite and on track
    ok = res["outcome"] == OUTCOME_RESULT
    for f in ("px", "py", "pz", "var_x", "var_y", "var_z"):
        assert np.all(np.isfinite(res[f][ok]))
    truth = flight.truth.position_at(res["t_us"][ok].astype(np.int64))
    err = np.linalg.norm(np.stack([res["px"][ok], res["py"][ok], res["pz"][ok]], 1) - truth, axis=1)
    assert float(np.sqrt(np.mean(err**2))) < 0.3
    # 5. the JSONL file has every measurement exactly once, LOST ones included
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    rows = [x for x in lines if x["type"] == "result"]
    assert [x["index"] for x in rows] == list(range(len(res)))
    assert Counter(x["outcome"] for x in rows)[OUTCOME_LOST] == len(lost_meas)


def test_rx_faults_lose_results_which_are_reported_lost(device: HostDevice) -> None:
    flight = _flight(6.0, mode="tdoa", seed=6)
    rates = FaultRates(bit_flip=3e-4, drop_frame=0.01, truncate_frame=0.005, garbage=0.005, drop_byte=1e-4)
    run, link, stats0 = _run_faulty(device, flight, FaultRates(), rates, seed=22)
    rx = link.rx_log
    d = _delta(run.stats, stats0)
    res = run.results
    assert d["seq_gaps"] == d["crc_errors"] == d["framing_errors"] == 0     # nothing lost towards the device
    assert d["results"] == len(res)                                          # the device answered everything
    lost = rx.lost_seqs
    assert len(lost) > 5
    lost_rows = set(unwrap_seqs(res["meas_seq"])[res["outcome"] == OUTCOME_LOST].tolist())
    assert lost_rows == lost
    # the host decoder counted what the link delivered broken
    assert run.decoder_errors.crc_errors == rx.delivered.errors.crc_errors
    assert run.decoder_errors.framing_errors == rx.delivered.errors.framing_errors
    ok = res["outcome"] == OUTCOME_RESULT
    assert np.all(np.isfinite(res["px"][ok])) and int(ok.sum()) == len(res) - len(lost)


def test_stalls_and_duplicates_do_not_change_the_estimates(device: HostDevice, tmp_path: Path) -> None:
    """Stalls only delay; a duplicated IMU/UWB frame at the same time stamp may change the estimate a
    little (it is processed twice), so duplicates are checked for accounting, stalls for identity."""
    flight = _flight(4.0, seed=7)
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev2:   # started with `device`: same binary
        dev2.hello(timeout=10.0)
        clean, _, _ = _run_faulty(device, flight, FaultRates(), FaultRates(), seed=1)
        stalled, link, _ = _run_faulty(dev2, flight, FaultRates(stall=0.02, stall_s=0.03),
                                       FaultRates(stall=0.02, stall_s=0.03), seed=2)
    assert link.tx_log.counts["stalls"] + link.rx_log.counts["stalls"] > 0
    assert np.all(stalled.results["outcome"] == OUTCOME_RESULT)
    for f in FIELDS_COMPARED:
        assert np.array_equal(clean.results[f], stalled.results[f]), f


def test_seq_unwrap_counts_across_wraps() -> None:
    seqs = [(65530 + k) & 0xFFFF for k in range(20)]
    seqs.insert(5, seqs[4])                          # a duplicate
    del seqs[12:14]                                  # two lost frames
    out = unwrap_seqs(seqs)
    assert out[0] == 65530 and out[-1] == 65530 + 19 and list(out[4:6]) == [65534, 65534]
    assert np.all(np.diff(out) >= 0)
    u = SeqUnwrap()
    assert [u(s) for s in (10, 9, 11)] == [10, 9, 11]    # a step back stays a step back


def test_faulty_link_is_seeded_and_counts() -> None:
    """Same seed, same faults: the injector is reproducible (the rest of the suite relies on it)."""
    from protocol.framing import encode_frame as enc
    stream = b"".join(enc(m.Twr(t_us=i, anchor_id=1, range=2.0), i) for i in range(2000))

    class Sink:
        name, closed = "sink", False

        def __init__(self) -> None:
            self.data = bytearray()

        def write(self, b: bytes) -> None:
            self.data += b

    outs = []
    for _ in range(2):
        sink = Sink()
        link = FaultyLink(sink, tx=FaultRates(bit_flip=1e-3, drop_frame=0.05, duplicate_frame=0.05),  # type: ignore[arg-type]
                          seed=4)
        link.write(stream[:1000])
        link.write(stream[1000:])
        outs.append((bytes(sink.data), dict(link.tx_log.counts)))
    assert outs[0] == outs[1]
    counts = outs[0][1]
    assert counts["frames"] == 2000 and 50 < counts["dropped_frames"] < 150
    assert len(link.tx_log.lost_seqs) >= counts["dropped_frames"]


# ------------------------------------------------------------------------------------ bad CONFIG
GOOD = EstimatorConfig()


def _config_msg(cfg: EstimatorConfig, reset: int = 1, **raw: float | int) -> m.Config:
    """CONFIG carrying ``cfg`` with some fields overwritten by raw (possibly invalid) values."""
    return replace(cfg.to_message(reset=reset), **raw)


BAD, NONFIN = int(m.ErrorCode.BAD_CONFIG), int(m.ErrorCode.NON_FINITE)
BAD_CONFIGS = [
    ("negative std_twr", dict(std_twr=-0.1), BAD),
    ("zero std_tdoa", dict(std_tdoa=0.0), BAD),
    ("negative process noise", dict(proc_acc_xy=-1.0), BAD),
    ("negative chi2 threshold", dict(chi2_twr=-3.0), BAD),
    ("NaN chi2 threshold", dict(chi2_twr=float("nan")), NONFIN),
    ("inf a_max", dict(a_max_twr=float("inf")), NONFIN),
    ("NaN init position", dict(init_x=float("nan")), NONFIN),
    ("unknown mode", dict(mode=7), BAD),
    ("unknown stage bits", dict(stages=0x88), BAD),   # 0x80: no stage (BIAS_STATES took 0x40)
    ("reset not 0/1", dict(reset=2), BAD),
    ("unknown tdoa_match", dict(tdoa_match=3), BAD),   # the byte that was reserved (protocol 9)
]


def _session(device: HostDevice, bad: list[m.Config]) -> tuple[list[m.Result], list[m.Error], m.Stats]:
    """Good CONFIG at (1, 1, 0.5), anchors, then `bad` CONFIGs (each with reset and another init
    point and noise), then TWR measurements; returns RESULTs, ERRORs and STATS."""
    anchors = [(0, -3.0, -3.0, 0.2), (1, 3.0, -3.0, 2.5), (2, 3.0, 3.0, 0.2), (3, -3.0, 3.0, 2.5)]
    ch = device.channel
    good = replace(GOOD, mode=1, stages=6).with_init(1.0, 1.0, 0.5)
    ch.send(_config_msg(good))
    for a in anchors:
        ch.send(m.Anchor(anchor_id=a[0], x=a[1], y=a[2], z=a[3]))
    bad_seqs = [ch.send(b) for b in bad]
    tag = np.array([1.2, 0.8, 0.6])
    for k in range(40):
        a = anchors[k % 4]
        ch.send(m.Twr(t_us=10_000 * (k + 1), anchor_id=a[0], range=float(np.linalg.norm(tag - np.array(a[1:])))))
    ch.send(m.StatsReq())
    results, errors, stats = [], [], None
    while stats is None:
        f = ch.recv(5.0)
        assert f is not None, "device went silent"
        if isinstance(f.msg, m.Result):
            results.append(f.msg)
        elif isinstance(f.msg, m.Error):
            errors.append(f.msg)
        elif isinstance(f.msg, m.Stats):
            stats = f.msg
    assert [e.msg_seq for e in errors] == bad_seqs
    return results, errors, stats


def test_bad_config_values_are_refused_and_change_nothing(device: HostDevice, tmp_path: Path) -> None:
    bad = [_config_msg(replace(GOOD, std_twr=0.9, chi2_twr=100.0).with_init(-2.0, 2.0, 2.0), **raw)
           for _, raw, _ in BAD_CONFIGS]
    results, errors, stats = _session(device, bad)
    assert [(e.code, e.msg_type) for e in errors] == [(int(code), m.Config.MSG_ID) for _, _, code in BAD_CONFIGS]
    assert stats.bad_configs == sum(1 for *_, code in BAD_CONFIGS if code == BAD)
    assert stats.non_finite == sum(1 for *_, code in BAD_CONFIGS if code == NONFIN)
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as ref_dev:
        ref_dev.hello(timeout=10.0)
        ref, ref_errors, _ = _session(ref_dev, [])
    assert ref_errors == [] and len(results) == len(ref) == 40
    for r, q in zip(results, ref):
        for f in FIELDS_COMPARED:
            assert getattr(r, f) == getattr(q, f), f


def test_huge_init_std_is_accepted_and_stays_bounded(device: HostDevice) -> None:
    """Regression (fuzz finding): init_std_xy = 1e20 is valid; its square used to be inf in the device."""
    huge = [_config_msg(replace(GOOD, mode=1, stages=6), init_std_xy=1e20, init_std_z=1e20)]
    ch = device.channel
    ch.send(huge[0])
    ch.send(m.Anchor(anchor_id=0, x=0.0, y=0.0, z=0.0))
    ch.send(m.Twr(t_us=1000, anchor_id=0, range=2.0))
    f = ch.expect(lambda fr: isinstance(fr.msg, (m.Result, m.Error)), 5.0, "RESULT")
    assert isinstance(f.msg, m.Result)
    r = f.msg
    assert all(math.isfinite(getattr(r, k)) for k, _ in m.Result.FIELDS if isinstance(getattr(r, k), float))
    assert 0 < r.var_x <= 100.0 and 0 < r.var_z <= 100.0
