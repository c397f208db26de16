"""The take-off and touchdown detector (firmware_sim/core/takeoff.c, harness/twin/takeoff.py): before the climb
and after a touchdown the gates do not re-open, so the floor's NLOS (links to low anchors metres long) cannot drag
the estimate; with CONFIG floor_imu in the UWB-only mode too, and with no outlier stage."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dataclasses import replace

from harness.config import MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, STAGES_OUTLIER
from harness.flight.data import KIND_TDOA, Anchors, Flight, ImuStream, Truth, UwbStream
from harness.twin.estimator import TwinEstimator, run_flight
from harness.twin.takeoff import CLIMB_V, TOUCH_ACC, TakeoffDetector
from core_replay import assert_core_equals_twin, base_config, f32, replay_core, run_c  # noqa: F401

ANCHORS = np.array([[-3, -4, 0.2], [-3, 4, 3.0], [4, 4, 0.2], [4, -4, 3.2], [-3, -4.4, 3.0], [4, -3.8, 0.2],
                    [4, 3.8, 3.1], [-3, 3.4, 0.2]], dtype=np.float64)
G = 9.81


def climb(t: np.ndarray, land: float = 99.0) -> tuple[np.ndarray, np.ndarray]:
    """Height [m] and vertical acceleration: 2 s on the floor at 0.1 m, then 1 s at +1 m/s^2, 1 s at -1, hover;
    from ``land`` [s] the mirror image down to the floor (2 s), where a 20 ms shock of 15 m/s^2 ends it."""
    def up(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = np.where((t >= 2.0) & (t < 3.0), 1.0, np.where((t >= 3.0) & (t < 4.0), -1.0, 0.0))
        z = 0.1 + np.where(t < 3.0, 0.5 * np.clip(t - 2.0, 0.0, None) ** 2, 0.5 + np.clip(t - 3.0, 0, 1.0)
                           - 0.5 * np.clip(t - 3.0, 0, 1.0) ** 2)
        return z, a
    z, a = up(t)
    z_down, a_down = up(np.clip(land + 4.0 - t, 0.0, None))
    down = t >= land
    shock = (t >= land + 2.0) & (t < land + 2.02)
    return np.where(down, z_down, z), np.where(down, a_down, a) + 15.0 * shock


def floor_takeoff_flight(seed: int = 2, land: float = 99.0, end_s: float = 6.0, nlos_below: float = 0.12) -> Flight:
    """TDoA2 pairs at 400 Hz; while the tag is on the floor (below nlos_below) every link to a low anchor reads
    3 m long."""
    rng = np.random.default_rng(seed)
    t_imu = np.arange(0, int(end_s * 1e6) + 1, 1000, dtype=np.int64)
    _, a_z = climb(t_imu * 1e-6, land)
    acc = np.zeros((len(t_imu), 3))
    acc[:, 2] = G + a_z + 0.3 * rng.standard_normal(len(t_imu))
    t_uwb = np.arange(1250, int(end_s * 1e6), 2500, dtype=np.int64)
    z, _ = climb(t_uwb * 1e-6, land)
    pos = np.stack([np.full_like(z, 1.5), np.full_like(z, 0.2), z], axis=1)
    k = np.arange(len(t_uwb))
    a, b = (k + 7) % 8, k % 8
    true = np.linalg.norm(pos - ANCHORS[b], axis=1) - np.linalg.norm(pos - ANCHORS[a], axis=1)
    low = ANCHORS[:, 2] < 1.0
    nlos = (z < nlos_below) * 3.0 * (low[b].astype(float) - low[a].astype(float))
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


def test_touchdown_puts_the_vehicle_back_on_the_floor() -> None:
    d = TakeoffDetector()
    t = np.arange(0, 10_000_001, 1000)
    _, a_z = climb(t * 1e-6, land=5.0)
    seen = np.array([d.on_imu(int(ti), G + float(ai), 1.0) for ti, ai in zip(t, a_z)])
    shock = np.flatnonzero(a_z > TOUCH_ACC)[0]
    assert seen[3000:shock].all() and not seen[shock:].any()      # airborne until the shock, then on the floor
    assert d.on_floor(True, int(t[-1])) and not d.on_floor(False, int(t[-1]))
    again = [d.on_imu(int(ti), G + 1.0, 1.0) for ti in t[-1] + 1000 * np.arange(1, 1001)]
    assert not again[0] and again[-1]                             # the next climb takes it off again


def test_floor_rule_in_uwb_only_and_without_stages(replay_core: Path) -> None:  # noqa: F811
    """A flight that lands (shock at 9 s) and sits 2 s on the floor, its NLOS from the touchdown on: with floor_imu
    the UWB-only filter (the IMU only tells take-off and touchdown) and the IMU filter without any outlier stage
    stay on the floor."""
    flight = floor_takeoff_flight(land=7.0, end_s=11.0, nlos_below=0.1 + 1e-9)
    on_floor = flight.truth.pos[:, 2] < 0.1 + 1e-9
    for mode, stages in ((MODE_UWB_ONLY, STAGES_OUTLIER), (MODE_IMU, 0)):
        cfg = base_config(flight, mode, stages)
        err = {f: np.linalg.norm(np.array([r.pos for r in run_flight(flight, replace(cfg, floor_imu=f))])
                                 - flight.truth.pos, axis=1) for f in (0, 1)}
        # held on the floor, before and after the flight (0.06 / 0.41 m: without a stage, only the floor's two
        # unbiased pairs pass the chi-square test there); without the rule the NLOS links drag it metres away
        assert err[1][on_floor].max() < 0.6 and err[0][on_floor].max() > 3.0, (mode, stages)
        assert np.sqrt(np.mean(err[1][~on_floor] ** 2)) < 0.1
        with_rule = replace(cfg, floor_imu=1)
        assert_core_equals_twin(run_c(replay_core, flight, with_rule), run_flight(flight, with_rule))
