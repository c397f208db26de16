"""The tag's TDoA engine (firmware_sim/core/tdoa_engine.c, lps_packets.c) against its twin and the
radio simulator's truth: clock correction, wrap-around, reboots, packet loss, malformed payloads."""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from harness.flight.measurement_errors import DW1000_TICK_M
from harness.flight.data import Flight, RadioStream
from harness.flight.radio_packets import RemoteInfo, tdoa2_payload, tdoa3_payload
from harness.flight.radio_sim import RadioConfig, simulate_radio
from harness.flight.scenarios import scenario_flight
from harness.twin import lps_packets as lp
from harness.twin.tdoa_engine import (DROP_CLOCK, DROP_MALFORMED, DROP_NO_REFERENCE, DROP_UNKNOWN_TYPE, MASK32,
                                      MATCH_AUTO, MATCH_YOUNGEST, MEASUREMENT, TdoaEngine, replay)

FW = Path(__file__).resolve().parents[2] / "firmware_sim"


@pytest.fixture(scope="session")
def tdoa_replay(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """firmware_sim/tools/tdoa_replay built with the firmware's warnings and the sanitizers."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    exe = tmp_path_factory.mktemp("tdoa") / "tdoa_replay"
    cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wstrict-prototypes", "-Wmissing-prototypes",
           "-Icore", "-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-o", str(exe),
           "core/lps_packets.c", "core/tdoa_clock.c", "core/tdoa_engine.c", "core/time_ms.c",
           "tools/tdoa_replay.c"]
    subprocess.run(cmd, cwd=FW, check=True, capture_output=True, text=True)
    return exe


def _payloads(r: RadioStream) -> list[bytes]:
    return [bytes(r.payload[k, :int(r.length[k])]) for k in range(len(r))]


def run_c(exe: Path, t_us: list[int], rx_ts: list[int], src: list[int], payloads: list[bytes]) -> tuple[list, dict]:
    lines = [f"P {int(t)} {int(rx)} {int(s) & 0xFF} {p.hex() or '-'}" for t, rx, s, p in zip(t_us, rx_ts, src, payloads)]
    out = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True, text=True, check=True,
                         timeout=120).stdout.split("\n")
    res, clocks = [], {}
    for line in out:
        f = line.split()
        if not f:
            continue
        if f[0] == "M":
            res.append((MEASUREMENT, int(f[1]), int(f[2]), float(f[4]), int(f[3])))
        elif f[0] == "D":
            res.append((int(f[1]), -1, -1, 0.0, 0))
        else:
            clocks[int(f[1])] = (int(f[2]), float(f[3]), int(f[4]))
    return res, clocks


def run_twin(t_us: list[int], rx_ts: list[int], src: list[int], payloads: list[bytes]) -> tuple[list, TdoaEngine]:
    eng, out = replay(t_us, rx_ts, src, payloads)
    return [(rc, m.anchor_a, m.anchor_b, m.diff, int(m.ticks)) if m is not None else (rc, -1, -1, 0.0, 0)
            for rc, m in out], eng


def _radio_flight(protocol: str, seed: int = 1, duration_s: float = 8.0, scenario: str = "circle",
                  **kw: object) -> Flight:
    base = scenario_flight(scenario, mode="tdoa2", duration_s=duration_s, seed=seed, noise="none")
    return simulate_radio(base, RadioConfig(protocol=protocol, seed=seed, **kw), None)  # type: ignore[arg-type]


def _cols(r: RadioStream) -> tuple[list[int], list[int], list[int], list[bytes]]:
    return r.t_us.tolist(), [int(v) for v in r.rx_ts], [int(v) for v in r.src_addr], _payloads(r)


@pytest.mark.parametrize("protocol,kw", [("tdoa2", {}), ("tdoa3", {}), ("tdoa3", {"loss": 0.3}),
                                         ("tdoa2", {"reboots": ((3, 2.0),), "loss": 0.1})])
def test_c_engine_equals_twin(tdoa_replay: Path, protocol: str, kw: dict) -> None:
    f = _radio_flight(protocol, **kw)
    cols = _cols(f.radio)  # type: ignore[arg-type]
    c, c_clocks = run_c(tdoa_replay, *cols)
    t, eng = run_twin(*cols)
    assert len(c) == len(t) == len(f.radio)  # type: ignore[arg-type]
    assert [x[:3] for x in c] == [x[:3] for x in t]
    assert [x[4] for x in c] == [x[4] for x in t]      # the same whole ticks
    diff = np.array([x[3] for x in c]) - np.array([x[3] for x in t])
    assert np.max(np.abs(diff)) < 1e-9
    for aid, (bucket, cc, packets) in c_clocks.items():
        a = eng.anchor(aid)
        assert a is not None and a.bucket == bucket and a.packets == packets
        assert abs(a.cc - cc) < 1e-15
    assert sum(1 for x in t if x[0] == MEASUREMENT) > 0.5 * len(t)


def _skew_and_errors(f: Flight, match: int = MATCH_AUTO) -> tuple[dict[int, float], np.ndarray, np.ndarray]:
    """Engine skew error per anchor [ppm], per measurement: total error and the clock-correction part [m]."""
    r = f.radio
    assert r is not None
    eng = TdoaEngine()
    total, clock = [], []
    ap = {int(i): p for i, p in zip(f.anchors.ids, f.anchors.positions)}
    assert r.true_skew_pkt is not None
    for k, (t, rx, src, p) in enumerate(zip(*_cols(r))):
        sender = src & 0xFF
        rc, pkt = lp.parse(p, sender)
        ref_rx = {a.id: a.rx_ts for a in eng.slots if a is not None}
        rc, m = eng.process(pkt, sender, rx, t, match)
        if rc == MEASUREMENT and m is not None:
            pos = f.truth.position_at(np.array([t]))[0]
            total.append(m.diff - (np.linalg.norm(pos - ap[sender]) - np.linalg.norm(pos - ap[m.anchor_a])))
            cc = eng.anchor(sender).cc  # type: ignore[union-attr]
            cc_true = 1.0 + float(r.true_skew_pkt[k]) * 1e-6
            clock.append((cc - cc_true) * ((rx - ref_rx[m.anchor_a]) & MASK32) * DW1000_TICK_M)
    skew_err = {a: (eng.anchor(a).cc - 1.0) * 1e6 - s for a, s in r.true_skew_ppm.items()}  # type: ignore[union-attr]
    return skew_err, np.array(total), np.array(clock)


def _exact_errors(f: Flight, match: int = MATCH_AUTO) -> np.ndarray:
    """The engine twin over the simulator's unrounded stamps (RadioConfig.exact_stamps): per measurement,
    the difference minus the true one at the reception [m]. No DW1000 tick: what is left is the clock
    correction's error (and the tag's motion between the two receptions)."""
    r = f.radio
    assert r is not None and r.exact is not None and r.exact_rx is not None
    ap = {int(i): p for i, p in zip(f.anchors.ids, f.anchors.positions)}
    eng = TdoaEngine(whole_ticks=False)
    err = []
    for k, (t, src) in enumerate(zip(r.t_us.tolist(), r.src_addr.tolist())):
        rc, m = eng.process(r.exact[k], int(src) & 0xFF, float(r.exact_rx[k]), int(t), match)
        if rc == MEASUREMENT and m is not None:
            p = f.truth.position_at(np.array([t]))[0]
            err.append(m.diff - (np.linalg.norm(p - ap[m.anchor_b]) - np.linalg.norm(p - ap[m.anchor_a])))
    return np.array(err)


def _plausible(err: np.ndarray, share: float = 0.01) -> np.ndarray:
    """The errors without the 32-bit wraps a Crazyflie's engine (2026.08) lets through: a reference whose
    packet the sender received more than 2^32 ticks (67 ms) before it transmitted gives 2^32 (cc - 1) ticks
    (metres to hundreds of metres; TDoA3's random schedule, ~0.2 % of measurements). The baseline check
    (REJECTED_BASELINE) or the gates discard them downstream. At most `share` of the measurements."""
    wrapped = np.abs(err) > 1.0
    assert np.count_nonzero(wrapped) <= share * len(err)
    return err[~wrapped]


@pytest.mark.parametrize("protocol,match,clock_mm", [("tdoa2", MATCH_AUTO, 1.0), ("tdoa3", MATCH_AUTO, 2.0),
                                                     ("tdoa3", MATCH_YOUNGEST, 1.0)])
def test_clock_correction_converges_and_reconstructs(protocol: str, match: int, clock_mm: float) -> None:
    """Clocks at constant skews within +-10 ppm, hovering tag, no noise: skew within 0.05 ppm of the
    truth. The reconstruction error the clocks cause, without the DW1000 tick (unrounded stamps), is
    < 1 mm RMS (measured 0.001 mm, both protocols); with the integer stamps of the wire, the clock-
    correction part (cc error x interval; the cc estimate sees the ticks too) is 0.18 mm TDoA2 (youngest),
    1.4 mm TDoA3 with a Crazyflie's rotating ("random") reference, ~20 ms old (0.34 mm with the youngest,
    ~3 ms old); the total is the tick's own quantisation (+-0.5 tick per timestamp, ~2.6 mm RMS) plus the
    whole-tick truncation of the difference."""
    f = _radio_flight(protocol, scenario="hover", duration_s=10.0, walk_ppm=0.0, exact_stamps=True)
    skew_err, total, clock = _skew_and_errors(f, match)
    assert max(abs(v) for v in skew_err.values()) < 0.05
    exact = _exact_errors(f, match)
    assert len(exact) == len(total) > 0.9 * len(f.radio)  # type: ignore[arg-type]
    ok = np.abs(total) < 1.0
    exact, total, clock = _plausible(exact), _plausible(total), clock[ok]
    assert np.sqrt(np.mean(exact ** 2)) < 1e-3
    assert np.sqrt(np.mean(clock ** 2)) < clock_mm * 1e-3
    assert np.sqrt(np.mean(total ** 2)) < 0.8 * DW1000_TICK_M
    spread = [abs(s) for s in f.radio.true_skew_ppm.values()]  # type: ignore[union-attr]
    assert max(spread) > 5.0   # the clocks really drift apart


@pytest.mark.parametrize("protocol,match,mm", [("tdoa2", MATCH_AUTO, 1.0), ("tdoa3", MATCH_AUTO, 6.0),
                                               ("tdoa3", MATCH_YOUNGEST, 2.0)])
def test_walking_clocks_without_tick(protocol: str, match: int, mm: float) -> None:
    """Skews random-walking at the simulator's default 0.02 ppm/sqrt(s), unrounded stamps: the cc (an average
    over the sender's last packet interval, 17 / 23 ms) lags the walk, and the difference multiplies its error
    by the reference's age; measured 0.49 mm RMS (TDoA2), 4.3 mm (TDoA3, a Crazyflie's rotating reference),
    1.5 mm (TDoA3, youngest)."""
    f = _radio_flight(protocol, scenario="hover", duration_s=10.0, walk_ppm=0.02, exact_stamps=True)
    rms = float(np.sqrt(np.mean(_plausible(_exact_errors(f, match)) ** 2)))
    print(f"{protocol}: clock-driven error with walking skews {1e3 * rms:.2f} mm RMS")
    assert rms < mm * 1e-3


def test_exact_stamps_change_nothing_on_the_wire() -> None:
    """The analysis option only adds the unrounded copy: packets and measurement-level twin unchanged."""
    a = _radio_flight("tdoa3", duration_s=3.0)
    b = _radio_flight("tdoa3", duration_s=3.0, exact_stamps=True)
    ra, rb = a.radio, b.radio
    assert ra is not None and rb is not None and ra.exact is None and rb.exact is not None
    assert np.array_equal(ra.rx_ts, rb.rx_ts) and np.array_equal(ra.payload, rb.payload)
    assert np.array_equal(a.uwb.value, b.uwb.value)
    assert len(rb.exact) == len(rb) and np.max(np.abs(rb.exact_rx - rb.rx_ts.astype(np.float64))) <= 0.5 + 1e-3


@pytest.mark.parametrize("protocol,match,ticks", [("tdoa2", MATCH_AUTO, 1.0), ("tdoa3", MATCH_AUTO, 2.5),
                                                  ("tdoa3", MATCH_YOUNGEST, 1.2)])
def test_clock_tracks_drift(protocol: str, match: int, ticks: float) -> None:
    """Skews random-walking (0.05 ppm/sqrt(s), 2.5x the default): estimates stay within 0.05 ppm; the
    measurements within a tick RMS (TDoA2, measured 0.61) or 1.2 ticks (TDoA3, measured 0.97: the cc
    lags the walk over TDoA3's longer packet interval, and its error is multiplied by the reference's age:
    2.25 ticks with a Crazyflie's rotating reference, ~20 ms old)."""
    f = _radio_flight(protocol, scenario="hover", duration_s=10.0, walk_ppm=0.05)
    skew_err, total, _ = _skew_and_errors(f, match)
    assert max(abs(v) for v in skew_err.values()) < 0.05
    assert np.sqrt(np.mean(_plausible(total) ** 2)) < ticks * DW1000_TICK_M


@pytest.mark.parametrize("protocol", ["tdoa2", "tdoa3"])
def test_timestamp_noise(protocol: str) -> None:
    """1 cm white noise on every RX stamp and on every emission, 1 cm on the anchors' ToFs: the clock
    estimates stay within 0.05 ppm and the differences scatter as the noise adds up (<= 3 cm RMS)."""
    f = _radio_flight(protocol, scenario="hover", duration_s=8.0, rx_noise_m=0.01, tx_noise_m=0.01,
                      tof_noise_m=0.01)
    skew_err, total, _ = _skew_and_errors(f)
    assert max(abs(v) for v in skew_err.values()) < 0.05
    total = _plausible(total)
    rms = float(np.sqrt(np.mean(total ** 2)))
    assert 0.01 < rms < 0.03 and abs(float(np.mean(total))) < 0.003
    assert len(total) > 0.9 * len(f.radio)  # type: ignore[arg-type]


def test_wraparound_2_32_and_2_40() -> None:
    """A 20 s flight crosses the 40-bit wrap of the tag clock (17.2 s) and hundreds of 32-bit wraps:
    no measurement lost to it, none wrong."""
    f = _radio_flight("tdoa2", scenario="hover", duration_s=20.0)
    r = f.radio
    assert r is not None
    rx = r.rx_ts.astype(np.int64)
    assert np.any(np.diff(rx) < 0)  # the 40-bit counter wrapped during the flight
    _, total, _ = _skew_and_errors(f)
    assert len(total) > 0.98 * len(r)
    assert np.max(np.abs(total)) < 0.03


def _outcomes(f: Flight) -> list[int]:
    return [rc for rc, _ in replay(*_cols(f.radio))[1]]  # type: ignore[arg-type]


def test_anchor_reboot_recovers() -> None:
    f = _radio_flight("tdoa2", scenario="hover", duration_s=6.0, reboots=((2, 2.0),))
    r = f.radio
    assert r is not None
    out = _outcomes(f)
    sender = (r.src_addr & 0xFF).astype(int)
    t = (r.t_us - r.t_us[0]) * 1e-6
    after = (sender == 2) & (t > 3.5)
    assert not np.any((sender == 2) & (t > 2.05) & (t < 2.2))      # silent while rebooting
    assert all(out[k] == MEASUREMENT for k in np.nonzero(after)[0])  # back to normal
    _, total, _ = _skew_and_errors(f)
    assert np.max(np.abs(total)) < 0.03                                # no wrong measurement around it


def test_thirty_percent_packet_loss() -> None:
    f = _radio_flight("tdoa3", duration_s=8.0, loss=0.3)
    out = _outcomes(f)
    n_meas = sum(1 for o in out if o == MEASUREMENT)
    assert n_meas > 0.4 * len(out)
    skew_err, total, _ = _skew_and_errors(f)
    assert max(abs(v) for v in skew_err.values()) < 0.05
    assert np.max(np.abs(_plausible(total, 0.02))) < 0.1   # motion between the two receptions, no wrong match


def test_malformed_payloads_c_and_twin_agree(tdoa_replay: Path) -> None:
    good2 = tdoa2_payload(1, 5, 1000, [RemoteInfo(0, 4, 900, 33000)], (1.0, 2.0, 3.0))
    good3 = tdoa3_payload(5, 1000, [RemoteInfo(0, 4, 900, 33000), RemoteInfo(2, 1, 800, 0)], (1.0, 2.0, 0.5))
    nan_lpp = good3[:-12] + struct.pack("<3f", float("nan"), 0.0, 0.0)
    self3 = tdoa3_payload(5, 1000, [RemoteInfo(1, 4, 900, 33000), RemoteInfo(0, 4, 900, 33000)], None)
    # as a Crazyflie's tag: only an incomplete header is malformed; the rest is processed (here: the
    # sender's first packet, so CLOCK_UNRELIABLE) with what is valid
    cases = {
        b"": DROP_MALFORMED, b"\x01\x02": DROP_UNKNOWN_TYPE, good2[:56]: DROP_MALFORMED,
        good2[:60]: DROP_CLOCK, good2 + b"\x00": DROP_CLOCK, good3[:6]: DROP_MALFORMED,
        good3[:6] + b"\x09" + good3[7:]: DROP_CLOCK, good3[:12]: DROP_CLOCK, nan_lpp: DROP_CLOCK,
        good3[:-14] + b"\xf0\x03\x02": DROP_CLOCK, good3[:-14] + b"\x55": DROP_CLOCK, self3: DROP_CLOCK,
    }
    parsed = {k: lp.parse(p, 1) for k, p in enumerate(cases)}
    assert parsed[3][1].pos is None and parsed[4][1].pos == (1.0, 2.0, 3.0)        # partial LPP ignored
    assert parsed[8][1].pos is None and len(parsed[8][1].remote) == 2            # NaN position ignored
    assert len(parsed[6][1].remote) == 4 and len(parsed[7][1].remote) == 0       # entries that fit (LPP bytes
    assert parsed[6][1].pos is None                                              # read as entries, as a CF does)
    assert [r.id for r in parsed[11][1].remote] == [0]                           # the sender's own entry skipped
    rng = np.random.default_rng(7)
    payloads = list(cases) + [bytes(rng.integers(0, 256, int(rng.integers(0, 129)), dtype=np.uint8))
                              for _ in range(300)]
    payloads += [bytes([0x30]) + bytes(rng.integers(0, 256, 40, dtype=np.uint8)) for _ in range(200)]
    payloads += [bytes([0x22]) + bytes(rng.integers(0, 256, 70, dtype=np.uint8)) for _ in range(200)]
    n = len(payloads)
    cols = (list(range(0, 1000 * n, 1000)), [int(v) for v in rng.integers(0, 2**40, n)], [1] * n, payloads)
    c, _ = run_c(tdoa_replay, *cols)
    t, _ = run_twin(*cols)
    assert [x[:3] for x in c] == [x[:3] for x in t]
    for k, want in enumerate(cases.values()):
        assert t[k][0] == want, (k, t[k])
        alone, _ = run_twin(*[col[k:k + 1] for col in cols])   # each alone: the sender's first packet
        assert alone[0][0] == want, (k, alone[0])
    assert {x[0] for x in t} >= {DROP_MALFORMED, DROP_UNKNOWN_TYPE, DROP_CLOCK}


def test_no_reference_before_anchors_heard() -> None:
    """The first packets of a flight: first none of an anchor's clock is known, then no reference."""
    f = _radio_flight("tdoa2", duration_s=1.0)
    out = _outcomes(f)
    assert out[0] == DROP_CLOCK
    assert DROP_NO_REFERENCE in out[:40] or DROP_CLOCK in out[:40]
    assert out[-1] == MEASUREMENT


def _entries(f: Flight) -> list[tuple[float, int, list[tuple[int, int, bool]]]]:
    """(t [s], sender, [(remote id, rx stamp, full entry)]) of every packet, from the raw payloads."""
    r = f.radio
    assert r is not None
    out = []
    for t, src, p in zip(r.t_us.tolist(), r.src_addr.tolist(), _payloads(r)):
        a = int(src) & 0xFF
        if p[0] == lp.TYPE_TDOA2:
            ts = struct.unpack_from("<8I", p, 9)
            out.append((t * 1e-6, a, [(i, ts[i], True) for i in range(8) if i != a]))
        else:
            ent, off = [], 7
            for _ in range(p[6]):
                full = bool(p[off + 1] & 0x80)
                ent.append((p[off], struct.unpack_from("<I", p, off + 2)[0], full))
                off += 8 if full else 6
            out.append((t * 1e-6, a, ent))
    return out


def test_simulated_anchors_send_what_real_anchors_send() -> None:
    """TDoA2: a slot whose packet the anchor missed carries a zero stamp (not the stale one); TDoA3: a full
    entry (with the distance) whenever the anchor has one: short only while a rebooted anchor re-ranges."""
    for loss, lo, hi in ((0.0, 0.0, 0.01), (0.2, 0.15, 0.25)):
        pk = _entries(_radio_flight("tdoa2", duration_s=3.0, anchor_loss=loss))
        slots = [ts for t, _, ent in pk if t > pk[0][0] + 0.05 for _, ts, _ in ent]
        assert lo <= sum(ts == 0 for ts in slots) / len(slots) <= hi
    pk = _entries(_radio_flight("tdoa3", duration_s=4.0))
    assert all(full for _, _, ent in pk for _, _, full in ent)
    pk = _entries(_radio_flight("tdoa3", duration_s=4.0, reboots=((2, 1.0),)))
    t0 = pk[0][0]
    short = [(t - t0, a, rid) for t, a, ent in pk for rid, _, full in ent if not full]
    assert short and all(1.0 <= t <= 1.0 + 0.2 + 0.5 + 0.05 and 2 in (a, rid) for t, a, rid in short)
