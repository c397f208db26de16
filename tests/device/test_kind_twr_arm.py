"""The measurement kind TWR_ARM (a range from an antenna on a lever arm of the body origin the state estimates),
added by the recipe of docs/ARCHITECTURE.md "Adding a measurement kind": streamed end to end through the host
firmware, answered as its own kind, equal to the twin, and it puts the estimate on the body origin where a plain
TWR of the same ranges sits a lever arm away."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.device.host import HostDevice
from harness.flight.data import KIND_TWR, Flight
from harness.flight.run_config import config_for
from harness.flight.scenarios import scenario_flight
from harness.paths import DEFAULT_FIRMWARE
from harness.report.metrics import run_summary
from harness.stream.streamer import OUTCOME_RESULT, Pacing, RunResult, Streamer
from harness.twin.ekf import quat_to_rot
from harness.twin.estimator import run_flight
from protocol.messages import MeasKind

LEVER = (0.25, -0.10, 0.15)   # the antenna in the body frame [m]
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


def _arm_flight(kind: int) -> Flight:
    """A simulated TWR flight whose truth is the body origin, its ranges measured at the lever arm."""
    f = scenario_flight("spin", mode="twr", duration_s=12.0, seed=4, noise="gaussian")
    u = f.uwb
    p = f.truth.position_at(u.t_us)
    rot = np.stack([quat_to_rot(q) for q in f.truth.quat_at(u.t_us)])
    antenna = p + rot @ np.array(LEVER)
    true = np.linalg.norm(antenna - np.stack([f.anchors.position(int(i)) for i in u.anchor_a]), axis=1)
    assert u.true_value is not None
    value = true + (u.value - u.true_value)
    return replace(f, uwb=replace(u, kind=kind, value=value, true_value=true))


def _stream(flight: Flight, cfg: EstimatorConfig, tmp_path: Path) -> RunResult:
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        return Streamer(dev).run(flight, cfg, Pacing("windowed", 64))


@needs_fw
def test_twr_arm_streams_end_to_end_and_estimates_the_body_origin(tmp_path: Path) -> None:
    flight = _arm_flight(int(MeasKind.TWR_ARM))
    flight.validate()
    lx, ly, lz = LEVER
    cfg = replace(config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"]), lever_x=lx, lever_y=ly, lever_z=lz)
    run = _stream(flight, cfg, tmp_path)
    res = run.results
    assert len(res) == len(flight.uwb) and np.all(res["outcome"] == OUTCOME_RESULT)
    assert np.all(res["kind"] == MeasKind.TWR_ARM)
    # the device is the twin (float32 against float64)
    twin = np.array([r.pos for r in run_flight(flight, cfg)])
    dev = np.stack([res["px"], res["py"], res["pz"]], axis=1)
    assert np.max(np.abs(dev - twin)) < 5e-3
    # the same ranges as plain TWR: the estimate follows the antenna, a lever arm off the body origin
    plain = _arm_flight(KIND_TWR)
    twr = _stream(plain, config_for(plain, EstimatorConfig(), stages=PRESETS["outlier"]), tmp_path)
    rmse_arm = run_summary(run, flight)["accuracy"]["rmse"]   # type: ignore[index]
    rmse_twr = run_summary(twr, plain)["accuracy"]["rmse"]    # type: ignore[index]
    assert rmse_arm < 0.1 and rmse_twr > 0.15 and rmse_arm < 0.5 * rmse_twr   # 0.07 m against 0.32 m
