"""The measurement kind TOF (a downward range to the floor from a ranger at CONFIG tof_x/y/z, naming no anchor),
added by the recipe of docs/ARCHITECTURE.md "Adding a measurement kind": streamed end to end through the host
firmware as a flight's measurements (answered as its own kind, equal to the twin) and as the auxiliary stream of
a TDoA flight (fused, not scored: the device still equals the twin, and the height is pinned)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import PRESETS, EstimatorConfig
from harness.device.host import HostDevice
from harness.flight.data import KIND_TOF, Flight, UwbStream
from harness.flight.run_config import config_for
from harness.flight.scenarios import scenario_flight
from harness.paths import DEFAULT_FIRMWARE
from harness.stream.streamer import OUTCOME_RESULT, Pacing, RunResult, Streamer
from harness.twin.ekf import quat_to_rot
from harness.twin.estimator import run_flight
from protocol.messages import MeasKind, Status

OFFSET = (0.02, -0.01, -0.12)   # the ranger from the tag point, body frame [m]
needs_fw = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")


def _tof_stream(f: Flight, rate_hz: float = 25.0, std: float = 0.01, seed: int = 3) -> UwbStream:
    """The ranger's readings of a simulated flight: along the body's -z axis to the floor, with noise."""
    t = np.arange(int(f.uwb.t_us[0]) + 5000, int(f.uwb.t_us[-1]), int(1e6 / rate_hz), dtype=np.int64)
    rot = np.stack([quat_to_rot(q) for q in f.truth.quat_at(t)])
    s_z = f.truth.position_at(t)[:, 2] + rot[:, 2, :] @ np.array(OFFSET)
    value = s_z / rot[:, 2, 2] + np.random.default_rng(seed).normal(0.0, std, len(t))
    none = np.full(len(t), -1, dtype=np.int64)
    return UwbStream(kind=KIND_TOF, t_us=t, anchor_a=none, anchor_b=none, value=value)


def _config(f: Flight) -> EstimatorConfig:
    x, y, z = OFFSET
    return replace(config_for(f, EstimatorConfig(), stages=PRESETS["outlier"]), tof_x=x, tof_y=y, tof_z=z)


def _stream(flight: Flight, cfg: EstimatorConfig, tmp_path: Path) -> RunResult:
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        return Streamer(dev).run(flight, cfg, Pacing("windowed", 64))


def _positions(run: RunResult) -> np.ndarray:
    r = run.results
    return np.stack([r["px"], r["py"], r["pz"]], axis=1)


@needs_fw
def test_tof_streams_as_its_own_kind_equal_to_the_twin(tmp_path: Path) -> None:
    base = scenario_flight("spin", mode="twr", duration_s=6.0, seed=4, noise="gaussian")
    flight = replace(base, uwb=_tof_stream(base))
    flight.validate()
    cfg = _config(flight)
    run = _stream(flight, cfg, tmp_path)
    res = run.results
    assert len(res) == len(flight.uwb) and np.all(res["outcome"] == OUTCOME_RESULT)
    assert np.all(res["kind"] == MeasKind.TOF) and np.mean(res["status"] == Status.ACCEPTED) > 0.9
    twin = run_flight(flight, cfg)
    np.testing.assert_allclose(res["innovation"], [r.innovation for r in twin], atol=2e-4)
    np.testing.assert_allclose(res["innovation_var"], [r.innovation_var for r in twin], rtol=1e-3, atol=1e-7)
    np.testing.assert_allclose(_positions(run), [r.pos for r in twin], atol=5e-3)
    # the height follows the ranger (xy is unobserved: the IMU alone)
    z_err = res["pz"][20:] - flight.truth.position_at(flight.uwb.t_us[20:])[:, 2]
    assert np.sqrt(np.mean(z_err ** 2)) < 0.03


@needs_fw
def test_tof_as_auxiliary_stream_pins_the_height(tmp_path: Path) -> None:
    """A TDoA flight with biased links (+0.3 m on every difference to anchor 0's pairs, as NLOS does) with and
    without the ranger: the device equals the twin, one RESULT per TDoA measurement, z error cut."""
    f = scenario_flight("circle", mode="tdoa", duration_s=12.0, seed=4, noise="gaussian")
    biased = replace(f.uwb, value=f.uwb.value + 0.3 * (f.uwb.anchor_a == 0) - 0.3 * (f.uwb.anchor_b == 0))
    plain = replace(f, uwb=biased)
    with_tof = replace(plain, aux=_tof_stream(plain))
    with_tof.validate()
    cfg = _config(with_tof)
    run = _stream(with_tof, cfg, tmp_path)
    assert len(run.results) == len(f.uwb) and np.all(run.results["outcome"] == OUTCOME_RESULT)
    assert run.stats is not None and run.stats.divergences == 0
    np.testing.assert_allclose(_positions(run), [r.pos for r in run_flight(with_tof, cfg)], atol=5e-3)
    truth_z = f.truth.position_at(f.uwb.t_us)[:, 2]
    z_tof = np.sqrt(np.mean((run.results["pz"] - truth_z)[400:] ** 2))
    without = _stream(plain, cfg, tmp_path)
    z_plain = np.sqrt(np.mean((without.results["pz"] - truth_z)[400:] ** 2))
    assert z_tof < 0.03 and z_tof < 0.5 * z_plain
