"""The firmware's TDoA engine (C, via tools/tdoa_replay) and its twin against tests/unit/bitcraze_oracle.py,
an independent statement of a Crazyflie tag's rules: on the project's simulated TDoA2 / TDoA3 traffic and
on hand-built traffic with clock skews of +-10 ppm across the 32- and 40-bit wraps, the same
measurements (count), the same pairs and the same whole ticks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from harness.flight.radio_packets import RemoteInfo, tdoa2_payload, tdoa3_payload
from harness.twin.tdoa_engine import MATCH_AUTO, MATCH_RANDOM, MATCH_YOUNGEST
from tests.unit.bitcraze_oracle import Oracle, metres
from tests.unit.test_tdoa_engine import _cols, _radio_flight, run_c, run_twin, tdoa_replay  # noqa: F401

Cols = tuple[list[int], list[int], list[int], list[bytes]]


def _oracle(cols: Cols, match: int) -> list[tuple[int, int, int] | None]:
    oracles = {a: Oracle(a) for a in ("random", "youngest")}
    out: list[tuple[int, int, int] | None] = []
    for t, rx, src, p in zip(*cols):
        name = {MATCH_RANDOM: "random", MATCH_YOUNGEST: "youngest"}.get(match)
        name = name or ("youngest" if p[:1] == b"\x22" else "random")
        out.append(oracles[name].packet(int(t), int(rx), int(src) & 0xFF, p))
    return out


def _hand_built(protocol: str, seed: int, n_anchors: int = 6, seconds: float = 6.0) -> Cols:
    """Anchors with clocks skewed by up to +-10 ppm and random 40-bit offsets, a tag whose counter wraps
    2 s in; TDoA2: slots of 2^27 ticks; TDoA3: 25-50 Hz random schedule. Anchors hear each other with 10 %
    loss, the tag with 15 %; TDoA3 entries full or short at random."""
    rng = np.random.default_rng(seed)
    skew = rng.uniform(-10e-6, 10e-6, n_anchors + 1)
    off = rng.integers(0, 1 << 40, n_anchors + 1)
    off[-1] = (1 << 40) - int(2.0 * 63.8976e9)
    pos = rng.uniform(-4, 4, (n_anchors, 3))
    tag = np.array([0.3, -0.2, 1.0])

    def clock(k: int, t: float) -> int:
        return int(off[k] + round(t * 63.8976e9 * (1 + skew[k])))

    if protocol == "tdoa2":
        times = [(s * 2**27 / 63.8976e9, s % 8) for s in range(int(seconds * 63.8976e9 / 2**27)) if s % 8 < n_anchors]
    else:
        times = sorted((t, a) for a in range(n_anchors)
                       for t in np.cumsum(rng.uniform(0.02, 0.04, int(seconds / 0.02))) if t < seconds)
    heard: dict[int, dict[int, tuple[int, int]]] = {a: {} for a in range(n_anchors)}
    seq = [0] * n_anchors
    cols: Cols = ([], [], [], [])
    for t, a in times:
        rem = [RemoteInfo(b, s, rx & 0xFFFFFFFF, int(round(np.linalg.norm(pos[a] - pos[b]) / 0.0046917 + 32951)))
               for b, (s, rx) in sorted(heard[a].items())]
        tx = clock(a, t) & ~0x1FF                      # delayed TX: the emission is at the stamp
        t -= (clock(a, t) - tx) / (63.8976e9 * (1 + skew[a]))
        if protocol == "tdoa2":
            p = tdoa2_payload(a, seq[a], tx & 0xFFFFFFFF, rem, None)
        else:
            p = tdoa3_payload(seq[a], tx & 0xFFFFFFFF, rem[:8], None, [bool(rng.random() < 0.6) for _ in rem[:8]])
        for b in range(n_anchors):
            if b != a and rng.random() > 0.1:
                heard[b][a] = (seq[a], clock(b, t + np.linalg.norm(pos[a] - pos[b]) / 299792458.0))
        seq[a] = (seq[a] + 1) & 0x7F
        if rng.random() > 0.15:
            t_rx = t + np.linalg.norm(pos[a] - tag) / 299792458.0
            for col, v in zip(cols, (int(t_rx * 1e6) + 1_000_000, clock(n_anchors, t_rx) & ((1 << 40) - 1),
                                     0xBCCF000000000000 | a, p)):
                col.append(v)  # type: ignore[arg-type]
    return cols


def _compare(exe: Path, cols: Cols, match: int = MATCH_AUTO) -> dict[str, float]:
    want = _oracle(cols, match)
    c, _ = run_c(exe, *cols) if match == MATCH_AUTO else (None, None)
    tw, _ = run_twin(*cols) if match == MATCH_AUTO else _twin_with(cols, match)
    got = [(x[1], x[2], x[4]) if x[0] == 0 else None for x in tw]
    if c is not None:
        assert [(x[1], x[2], x[4]) if x[0] == 0 else None for x in c] == got    # C = twin, packet by packet
    n_want, n_got = sum(w is not None for w in want), sum(g is not None for g in got)
    both = [(w, g) for w, g in zip(want, got) if w is not None and g is not None]
    same_pair = sum(w[:2] == g[:2] for w, g in both)
    same_tick = sum(w == g for w, g in both)
    assert both and all(abs(metres(g[2]) - metres(w[2])) < 1e-9 for w, g in both if w == g)
    return {"oracle": n_want, "firmware": n_got, "pairs": same_pair / max(n_want, 1), "ticks": same_tick / max(n_want, 1)}


def _twin_with(cols: Cols, match: int) -> tuple[list, None]:
    from harness.twin.tdoa_engine import replay
    _, out = replay(*cols, match=match)
    return [(rc, m.anchor_a, m.anchor_b, m.diff, int(m.ticks)) if m is not None else (rc, -1, -1, 0.0, 0)
            for rc, m in out], None


def _assert_equal(r: dict[str, float]) -> None:
    assert r["oracle"] == r["firmware"] > 0
    assert r["pairs"] >= 0.99 and r["ticks"] >= 0.99


@pytest.mark.parametrize("protocol,kw", [("tdoa2", {}), ("tdoa3", {}), ("tdoa3", {"loss": 0.3}),
                                         ("tdoa2", {"reboots": ((3, 2.0),), "loss": 0.1}),
                                         ("tdoa3", {"reboots": ((1, 1.5),), "max_ppm": 10.0})])
def test_simulated_traffic_forms_what_a_crazyflie_forms(tdoa_replay: Path, protocol: str, kw: dict) -> None:
    f = _radio_flight(protocol, duration_s=8.0, **kw)
    r = _compare(tdoa_replay, _cols(f.radio))  # type: ignore[arg-type]
    print(protocol, kw, r)
    _assert_equal(r)


@pytest.mark.parametrize("protocol", ["tdoa2", "tdoa3"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_hand_built_skews_and_wraps(tdoa_replay: Path, protocol: str, seed: int) -> None:
    cols = _hand_built(protocol, seed)
    assert np.any(np.diff(np.array(cols[1], dtype=np.int64)) < 0)     # the tag's 40-bit counter wrapped
    r = _compare(tdoa_replay, cols)
    print(protocol, seed, r)
    _assert_equal(r)


@pytest.mark.parametrize("match", [MATCH_RANDOM, MATCH_YOUNGEST])
def test_either_matching_on_either_protocol(tdoa_replay: Path, match: int) -> None:
    for protocol in ("tdoa2", "tdoa3"):
        _assert_equal(_compare(tdoa_replay, _hand_built(protocol, 4), match))


def test_more_anchors_than_the_storage(tdoa_replay: Path) -> None:
    """20 TDoA3 anchors in view, 16 contexts: evictions, and the contexts a reference lookup creates (even the
    sender's own, when its context is the oldest: the search goes on through a copy of its records)."""
    cols = _hand_built("tdoa3", 5, n_anchors=20)
    assert len({s & 0xFF for s in cols[2]}) == 20
    r = _compare(tdoa_replay, cols)
    print("tdoa3 20 anchors", r)
    _assert_equal(r)
