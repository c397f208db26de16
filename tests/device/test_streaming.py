"""Long simulated flights built and streamed in slices (harness/flight/chunked.py,
harness/stream/chunked_run.py): same flight, same estimates, same summary as the whole flight, with
bounded memory (`make bench` prints the peak RSS of 600 s and 3600 s flights)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.device.host import HostDevice
from harness.flight.chunked import concat_flights
from harness.flight.data import Flight
from harness.flight.scenarios import plan_scenario, scenario_flight
from harness.report.metrics import run_summary
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE, REPO_ROOT
from harness.stream.chunked_run import stream_plan
from harness.stream.digest import FlightDigest, flight_digest
from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer

CASES = [("circle", "twr", "realistic", {}), ("random", "tdoa", "realistic", {"profile": "nlos"}),
         ("circle-z", "tdoa3", "gaussian", {}), ("spin", "twr", "none", {}),
         ("circle", "tdoa", "realistic", {"takeoff": True})]
ARRAYS = {"uwb": ("t_us", "anchor_a", "anchor_b", "value", "true_value"), "imu": ("t_us", "acc", "gyro"),
          "truth": ("t_us", "pos", "quat", "vel")}

needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


def _assert_same_flight(a: Flight, b: Flight) -> None:
    for part, names in ARRAYS.items():
        for name in names:
            x, y = getattr(getattr(a, part), name), getattr(getattr(b, part), name)
            assert np.array_equal(x, y), f"{part}.{name} differs"


@pytest.mark.parametrize("scenario,mode,noise,kw", CASES, ids=[f"{c[0]}-{c[1]}-{c[2]}" for c in CASES])
def test_flight_in_slices_equals_the_whole_flight(scenario: str, mode: str, noise: str, kw: dict) -> None:
    plan = plan_scenario(scenario, mode=mode, duration_s=16.0, seed=11, noise=noise, **kw)
    whole = scenario_flight(scenario, mode=mode, duration_s=16.0, seed=11, noise=noise, **kw)
    _assert_same_flight(plan.whole(), whole)
    for chunk_s in (1.0, 4.7):
        pieces = list(plan.chunks(chunk_s))
        assert len(pieces) == len(plan.bounds(chunk_s)) >= 3
        assert all(len(p.uwb) > 0 for p in pieces)
        _assert_same_flight(concat_flights(pieces), whole)    # bit for bit: same randomness, same values
        digest = FlightDigest()
        for i, p in enumerate(pieces):
            digest.update(p, last=i + 1 == len(pieces))
        assert digest.hexdigest() == flight_digest(whole)


def test_another_seed_gives_another_flight() -> None:
    a = list(plan_scenario("circle", duration_s=8.0, seed=1).chunks(3.0))[1]
    b = list(plan_scenario("circle", duration_s=8.0, seed=2).chunks(3.0))[1]
    assert not np.array_equal(a.uwb.value, b.uwb.value) and not np.array_equal(a.imu.acc, b.imu.acc)


def test_slices_hold_no_more_than_their_time() -> None:
    plan = plan_scenario("circle", mode="tdoa", duration_s=60.0, seed=3)
    sizes = [(len(p.imu), len(p.truth.t_us), len(p.uwb)) for p in plan.chunks(10.0)]
    assert [s[0] for s in sizes] == [10_000] * 5 + [plan.n_imu - 50_000]
    assert all(t == i + 1 for i, t, _ in sizes[:-1])               # one shared truth sample per boundary
    assert sum(s[2] for s in sizes) == plan.n_uwb and max(s[2] for s in sizes) <= 4001


@needs_fw
def test_streaming_in_slices_gives_the_same_estimates_and_summary(tmp_path: Path) -> None:
    plan = plan_scenario("circle", mode="twr", duration_s=20.0, seed=5)
    flight = plan.whole()
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        streamer = Streamer(dev)
        whole = streamer.run(flight, cfg, Pacing("windowed", 64))
        path = tmp_path / "r.jsonl"
        sliced = stream_plan(streamer, plan, lambda first: config_for(first, EstimatorConfig(),
                                                                      stages=PRESETS["outlier+nn"]),
                             Pacing("windowed", 64), chunk_s=6.0, results_path=path)
    assert sliced.chunks == 4
    a, b = whole.results, sliced.run.results
    assert len(b) == len(flight.uwb) and np.all(b["outcome"] == OUTCOME_RESULT)
    for name in ("t_us", "status", "px", "py", "pz", "var_x", "innovation"):
        assert np.array_equal(a[name], b[name]), name
    sa, sb = run_summary(whole, flight), run_summary(sliced.run, sliced.flight)
    assert sa["accuracy"] == sb["accuracy"] and sa["measurements"] == sb["measurements"]
    assert sliced.flight.imu is None and len(sliced.flight.truth.t_us) == len(flight.uwb)
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert lines[0]["type"] == "header" and lines[0]["flight_digest"] == flight_digest(flight)
    assert lines[0]["n_measurements"] == len(flight.uwb)
    assert [r["index"] for r in lines if r["type"] == "result"] == list(range(len(flight.uwb)))


@needs_fw
def test_cli_streams_a_long_simulation_in_slices(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "harness.cli", "run", "--duration", "130", "--json",
                          "--results", str(tmp_path / "long.jsonl")],
                         capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    n = plan_scenario("circle", mode="twr", duration_s=130.0, seed=1).n_uwb
    assert summary["measurements"] == summary["results"] == n
    assert summary["accuracy"]["rmse"] < 0.2
    rows = sum(1 for line in (tmp_path / "long.jsonl").read_text().splitlines() if '"type": "result"' in line)
    assert rows == n


@needs_fw
def test_sliced_flight_needs_a_fraction_of_the_memory() -> None:
    """Peak RSS (own subprocess each, harness/bench/memory.py) of a 240 s flight: sliced vs built whole."""
    from harness.bench.memory import measure
    sliced, whole = measure(240.0, "sliced"), measure(240.0, "whole")
    print(f"\n240 s TWR flight: peak RSS sliced {sliced['peak_rss_mb']:.0f} MB, whole {whole['peak_rss_mb']:.0f} MB")
    assert sliced["measurements"] == whole["measurements"] == sliced["results"]
    assert sliced["rmse_m"] == whole["rmse_m"]
    assert sliced["peak_rss_mb"] < 0.6 * whole["peak_rss_mb"]
    assert sliced["peak_rss_mb"] < 200.0
