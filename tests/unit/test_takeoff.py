"""The quadrotor model's take-off detector (firmware_sim/core/takeoff.c, harness/twin/takeoff.py): before the
climb the gates do not re-open, so the floor's NLOS (links to low anchors metres long) cannot drag the estimate."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from harness.config import MODE_IMU, MODE_IMU_THRUST
from harness.flight.data import KIND_TDOA, Anchors, Flight, ImuStream, Truth, UwbStream
from harness.twin.estimator import TwinEstimator, run_flight
from harness.twin.takeoff import CLIMB_V, TakeoffDetector
from core_replay import assert_core_equals_twin, base_config, f32, replay_core, run_c  # noqa: F401

ANCHORS = np.array([[-3, -4, 0.2], [-3, 4, 3.0], [4, 4, 0.2], [4, -4, 3.2], [-3, -4.4, 3.0], [4, -3.8, 0.2],
                    [4, 3.8, 3.1], [-3, 3.4, 0.2]], dtype=np.float64)
G = 9.81


def climb(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height [m] and vertical acceleration: 2 s on the floor at 0.1 m, then 1 s at +1 m/s^2, 1 s at -1, hover."""
    a = np.where((t >= 2.0) & (t < 3.0), 1.0, np.where((t >= 3.0) & (t < 4.0), -1.0, 0.0))
    z = 0.1 + np.where(t < 3.0, 0.5 * np.clip(t - 2.0, 0.0, None) ** 2, 0.5 + np.clip(t - 3.0, 0, 1.0)
                       - 0.5 * np.clip(t - 3.0, 0, 1.0) ** 2)
    return z, a


def floor_takeoff_flight(seed: int = 2) -> Flight:
    """TDoA2 pairs at 400 Hz; while the tag is on the floor every link to a low anchor reads 3 m long."""
    rng = np.random.default_rng(seed)
    t_imu = np.arange(0, 6_000_001, 1000, dtype=np.int64)
    _, a_z = climb(t_imu * 1e-6)
    acc = np.zeros((len(t_imu), 3))
    acc[:, 2] = G + a_z + 0.3 * rng.standard_normal(len(t_imu))
    t_uwb = np.arange(1250, 6_000_000, 2500, dtype=np.int64)
    z, _ = climb(t_uwb * 1e-6)
    pos = np.stack([np.full_like(z, 1.5), np.full_like(z, 0.2), z], axis=1)
    k = np.arange(len(t_uwb))
    a, b = (k + 7) % 8, k % 8
    true = np.linalg.norm(pos - ANCHORS[b], axis=1) - np.linalg.norm(pos - ANCHORS[a], axis=1)
    low = ANCHORS[:, 2] < 1.0
    nlos = (z < 0.12) * 3.0 * (low[b].astype(float) - low[a].astype(float))
    value = true + nlos + 0.05 * rng.standard_normal(len(k))
    uwb = UwbStream(kind=KIND_TDOA, t_us=t_uwb, anchor_a=a, anchor_b=b, value=f32(value), true_value=true)
    flight = Flight(name="floor-takeoff", anchors=Anchors(ids=np.arange(8), positions=ANCHORS), uwb=uwb,
                    truth=Truth(t_us=t_uwb, pos=pos),
                    imu=ImuStream(t_us=t_imu, acc=f32(acc), gyro=np.zeros((len(t_imu), 3))))
    flight.validate()
    return flight


def test_detector_sees_the_climb_not_the_floor() -> None:
    d = TakeoffDetector()
    t = np.arange(0, 4_000_001, 1000)
    _, a_z = climb(t * 1e-6)
    seen = [d.on_imu(int(ti), G + float(ai) - 0.05, 1.0) for ti, ai in zip(t, a_z)]   # a 0.05 m/s^2 bias
    first = t[int(np.argmax(seen))] * 1e-6
    assert not any(seen[:2000]) and 2.3 < first < 3.0            # within the climb, not on the floor
    assert d.climb_v < CLIMB_V and d.airborne                     # stays airborne after the climb


def test_floor_nlos_does_not_drag_the_estimate(replay_core: Path) -> None:  # noqa: F811
    flight = floor_takeoff_flight()
    on_floor = flight.truth.pos[:, 2] < 0.12
    thrust = run_flight(flight, base_config(flight, MODE_IMU_THRUST))
    full = run_flight(flight, base_config(flight, MODE_IMU))
    err = {name: np.linalg.norm(np.array([r.pos for r in res]) - flight.truth.pos, axis=1)
           for name, res in (("thrust", thrust), ("full", full))}
    assert err["thrust"][on_floor].max() < 0.3                    # held on the floor
    assert err["full"][on_floor].max() > 1.0                      # without the hold the NLOS links drag it
    assert np.sqrt(np.mean(err["thrust"][~on_floor] ** 2)) < 0.1
    twin = TwinEstimator(base_config(flight, MODE_IMU_THRUST), flight.anchors.as_dict())
    for t_us, acc_z in zip(flight.imu.t_us, flight.imu.acc[:, 2]):
        twin.takeoff.on_imu(int(t_us), float(acc_z), 1.0)
    assert twin.takeoff.airborne
    assert_core_equals_twin(run_c(replay_core, flight, base_config(flight, MODE_IMU_THRUST)), thrust)
