"""End to end through the plugin's device (the host firmware on a pty by default, a board with --uwb-port).

The firmware's estimates are checked against ground truth and against the numpy twin.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.flight.data import Source
from harness.flight.scenarios import scenario_flight
from harness.report.metrics import accuracy_summary
from harness.flight.run_config import config_for
from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer
from harness.twin.estimator import TwinEstimator


def _rmse(run, flight) -> float:  # noqa: ANN001
    return accuracy_summary(run, flight).rmse


def _twin_results(flight, cfg):  # noqa: ANN001, ANN202
    twin = TwinEstimator(cfg, flight.anchors.as_dict(), model=None)
    out = []
    u = flight.uwb
    for t, src, i in flight.events():
        if src == Source.IMU:
            twin.on_imu(t, flight.imu.acc[i], flight.imu.gyro[i])
        elif u.kind == 1:
            out.append(twin.on_twr(t, int(u.anchor_a[i]), float(u.value[i])))
        else:
            out.append(twin.on_tdoa(t, int(u.anchor_a[i]), int(u.anchor_b[i]), float(u.value[i])))
    return out


@pytest.mark.parametrize("mode", ["twr", "tdoa"])
def test_noiseless_flight_is_tracked_to_2cm(uwb_device, mode: str) -> None:  # noqa: ANN001
    flight = scenario_flight("circle", mode=mode, duration_s=12.0, seed=11, noise="none")
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["none"])
    run = Streamer(uwb_device).run(flight, cfg, Pacing("windowed", 64))
    assert run.n_received == len(flight.uwb)
    assert _rmse(run, flight) < 0.02


@pytest.mark.parametrize("mode", ["twr", "tdoa"])
def test_gaussian_noise_flight_and_twin_agree(uwb_device, mode: str) -> None:  # noqa: ANN001
    flight = scenario_flight("circle", mode=mode, duration_s=12.0, seed=12, noise="gaussian", noise_std=0.1)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    run = Streamer(uwb_device).run(flight, cfg, Pacing("windowed", 64))
    assert run.n_received == len(flight.uwb)
    assert _rmse(run, flight) < 0.15
    twin = _twin_results(flight, cfg)
    res = run.results
    assert [int(s) for s in res["status"]] == [int(r.status) for r in twin]
    c_pos = np.stack([res["px"], res["py"], res["pz"]], axis=1).astype(np.float64)
    t_pos = np.array([r.pos for r in twin])
    assert np.max(np.abs(c_pos - t_pos)) < 1e-4


def test_lockstep_and_windowed_give_identical_estimates(uwb_device) -> None:  # noqa: ANN001
    flight = scenario_flight("circle", mode="tdoa", duration_s=6.0, seed=13)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    streamer = Streamer(uwb_device)
    a = streamer.run(flight, cfg, Pacing("lockstep"))
    b = streamer.run(flight, cfg, Pacing("windowed", 128))
    for key in ("status", "innovation", "px", "py", "pz", "qw", "var_x"):
        assert np.array_equal(a.results[key], b.results[key]), key
    assert a.n_received == b.n_received == len(flight.uwb)


def test_realtime_pacing_follows_the_data_clock(uwb_device, uwb_target: str) -> None:  # noqa: ANN001
    # QEMU's emulated UART moves ~0.25x real time of a 1 kHz IMU + 200 Hz TWR stream: pace it slower.
    speed = 0.1 if uwb_target == "qemu" else 4.0
    flight = scenario_flight("circle", mode="twr", duration_s=2.0, seed=14)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    run = Streamer(uwb_device, timeout_s=30.0).run(flight, cfg, Pacing("realtime", speed=speed))
    assert run.n_received == len(flight.uwb)
    assert 0.8 * run.sim_s / speed <= run.wall_s <= run.sim_s / speed + 1.5 + 0.1 * run.sim_s / speed


def test_results_stream_to_jsonl(uwb_device, tmp_path: Path) -> None:  # noqa: ANN001
    flight = scenario_flight("circle", mode="twr", duration_s=3.0, seed=15)
    cfg = config_for(flight, EstimatorConfig())
    path = tmp_path / "run.jsonl"
    run = Streamer(uwb_device).run(flight, cfg, Pacing("windowed", 16), results_path=path)
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert lines[0]["type"] == "header" and lines[-1]["type"] == "stats"
    results = [rec for rec in lines if rec["type"] == "result"]
    assert len(results) == len(flight.uwb)
    assert [r["index"] for r in results] == list(range(len(flight.uwb)))
    assert lines[-1]["results"] >= len(flight.uwb)
    ok = run.results["outcome"] == OUTCOME_RESULT
    assert np.allclose([r["px"] for r in results], run.results["px"][ok].astype(float))
