"""The C estimator core against the numpy twin, without the wire protocol.

firmware_sim/tools/replay_core.c is compiled with the firmware's flags and fed a text event stream;
the twin gets the same (float32-rounded) flight. Statuses must match exactly and positions to
1e-4 m, in IMU and UWB-only mode, noiseless and with noise plus outliers (so the gates fire). With a bias
network: test_core_vs_twin_nn.py; the shared flight and replay helpers: core_replay.py.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core_replay import (assert_core_equals_twin, base_config, box_anchors, f32, replay_core, rmse,  # noqa: F401
                         run_c, synthetic_flight)
from harness.config import MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, STAGE_CHI2_GATE
from harness.flight.data import (KIND_TDOA, KIND_TWR, Anchors, Flight, HeightStream, ImuStream, Source, Truth,
                                 UwbStream)
from harness.twin.estimator import (ACCEPTED, FLAG_COVARIANCE, FLAG_DIVERGED, FLAG_GAP_RESTART, FLAG_HEIGHT_FUSED,
                                    FLAG_OUT_OF_BOX, FLAG_SPEED, REJECTED_CHI2, REJECTED_KINEMATIC, TwinEstimator,
                                    TwinResult, run_flight)


# ---------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
@pytest.mark.parametrize("noisy", [False, True], ids=["noiseless", "noise0.1+outliers"])
def test_core_matches_twin(replay_core: Path, mode: int, kind: int, noisy: bool) -> None:
    flight = synthetic_flight(kind, noise=0.1 if noisy else 0.0, outliers=noisy, seed=3 + kind)
    cfg = base_config(flight, mode)
    twin: list[TwinResult] = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)

    t_status = np.array([r.status for r in twin])
    t_pos = np.array([r.pos for r in twin])
    assert len(twin) == len(c.status) == len(flight.uwb)
    np.testing.assert_array_equal(c.status, t_status)
    assert np.max(np.abs(c.pos - t_pos)) < 1e-4
    assert np.max(np.abs(c.innovation - np.array([r.innovation for r in twin]))) < 1e-4
    assert np.max(np.abs(c.var - np.array([r.var for r in twin])) / np.array([r.var for r in twin])) < 1e-3
    assert c.divergences == 0

    limit = 0.15 if noisy else 0.02
    assert rmse(t_pos, flight) < limit
    assert rmse(c.pos, flight) < limit
    if noisy:
        assert np.sum(t_status == REJECTED_KINEMATIC) >= len(flight.uwb) // 97  # every injected +1 m
    else:
        assert np.all(t_status == ACCEPTED)


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
def test_chi2_gate_alone_matches_twin(replay_core: Path, mode: int) -> None:
    flight = synthetic_flight(KIND_TWR, noise=0.05, outliers=True, seed=9)
    cfg = replace(base_config(flight, mode, stages=STAGE_CHI2_GATE), std_twr=0.1)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    t_status = np.array([r.status for r in twin])
    np.testing.assert_array_equal(c.status, t_status)
    assert np.sum(t_status == REJECTED_CHI2) >= 2 * (len(flight.uwb) // 97)  # +1 m and -0.4 m outliers
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-4
    assert rmse(c.pos, flight) < 0.15


class _TwinWithoutGuard(TwinEstimator):
    """The twin with the chi-square gate's lock-out guard off (the gates before it)."""

    def _chi2_reopened(self) -> bool:
        return False


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
def test_chi2_lockout_guard_matches_twin(replay_core: Path, mode: int, kind: int) -> None:
    """Anchor 3's range 1 m too long from 3 s to 5 s (a blocked line of sight): the chi-square gate rejects
    its links at first and, once they have been rejected for GATE_CHI2_REOPEN_US, lets one through (then the
    clock starts again), C and twin alike; without the guard they stay rejected to the end of the episode."""
    flight = synthetic_flight(kind, noise=0.05, seed=13)
    u = flight.uwb
    on = (u.t_us >= 3_000_000) & (u.t_us < 5_000_000)
    offset = 1.0 * ((u.anchor_b == 3).astype(float) - (u.anchor_a == 3)) if kind == KIND_TDOA else 1.0 * (u.anchor_a == 3)
    flight = replace(flight, uwb=replace(u, value=f32(u.value + np.where(on, offset, 0.0))))
    cfg = base_config(flight, mode, stages=STAGE_CHI2_GATE)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    t_status = np.array([r.status for r in twin])
    np.testing.assert_array_equal(c.status, t_status)
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-4
    hit = on & (offset != 0)
    first = hit & (u.t_us < 3_150_000)       # within the guard time: rejected
    late = hit & (u.t_us >= 3_500_000)
    assert np.all(t_status[first] == REJECTED_CHI2)
    accepted = u.t_us[late & (t_status == ACCEPTED)]
    assert len(accepted) >= 4 and np.max(np.diff(accepted)) <= 300_000   # one at least every 0.3 s
    before = _TwinWithoutGuard(cfg, flight.anchors.as_dict())
    imu, uf, no_guard = flight.imu, flight.uwb, []
    assert imu is not None
    for t, source, i in flight.events():
        if source == Source.IMU:
            before.on_imu(t, imu.acc[i], imu.gyro[i])
        elif kind == KIND_TWR:
            no_guard.append(before.on_twr(t, int(uf.anchor_a[i]), float(uf.value[i])).status)
        else:
            no_guard.append(before.on_tdoa(t, int(uf.anchor_a[i]), int(uf.anchor_b[i]), float(uf.value[i])).status)
    assert not np.any(np.array(no_guard)[late] == ACCEPTED)   # locked out to the end of the episode


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
def test_supervisor_matches_twin(replay_core: Path, mode: int) -> None:
    """Gross range errors with the gates off throw the estimate out of the anchors' box: C and twin
    reset at the same measurements, with the same reasons, and carry on identically."""
    flight = synthetic_flight(KIND_TWR, noise=0.05, seed=5)
    value = flight.uwb.value.copy()
    value[400:403] += 40.0
    flight = replace(flight, uwb=replace(flight.uwb, value=f32(value)))
    cfg = replace(base_config(flight, mode, stages=0), std_twr=0.02)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    t_flags = np.array([r.flags for r in twin])
    np.testing.assert_array_equal(c.flags, t_flags)
    assert c.divergences >= 1 and c.divergences == int(np.count_nonzero(t_flags & FLAG_DIVERGED))
    events = t_flags[t_flags != 0]
    assert np.all(events & FLAG_DIVERGED) and np.any(events & FLAG_OUT_OF_BOX)
    assert np.all(events & (FLAG_OUT_OF_BOX | FLAG_SPEED))      # the 40 m jump: outside the box, or too fast
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-3
    assert rmse(c.pos[450:], replace(flight, truth=replace(flight.truth, pos=flight.truth.pos[450:]))) < 0.15


def _uwb_where(flight: Flight, keep: np.ndarray) -> Flight:
    u = flight.uwb
    return replace(flight, uwb=replace(u, t_us=u.t_us[keep], anchor_a=u.anchor_a[keep], anchor_b=u.anchor_b[keep],
                                       value=u.value[keep], true_value=u.true_value[keep]))


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
def test_measurement_gap_is_not_a_divergence_in_core_and_twin(replay_core: Path, mode: int) -> None:
    """A 5 s gap without measurements (rcv_twr sequences have 4-14 s on the ground): in UWB-only mode the
    prediction grows P past sup_max_var; C and twin restart from the last fix and report GAP_RESTART, not
    DIVERGED. With the IMU the variance stays under the bound over 5 s: nothing to report."""
    flight = synthetic_flight(KIND_TWR, noise=0.05, duration_s=12.0, seed=11)
    t = flight.uwb.t_us
    flight = _uwb_where(flight, (t < 3_000_000) | (t >= 8_000_000))
    cfg = base_config(flight, mode)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    t_flags = np.array([r.flags for r in twin])
    np.testing.assert_array_equal(c.flags, t_flags)
    assert c.divergences == 0 and not np.any(t_flags & FLAG_DIVERGED)
    after = int(np.searchsorted(flight.uwb.t_us, 8_000_000))
    if mode == MODE_UWB_ONLY:
        assert t_flags[after] == FLAG_GAP_RESTART and np.count_nonzero(t_flags) == 1
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-3
    err = c.pos[after + 200:] - flight.truth.position_at(flight.uwb.t_us[after + 200:])
    assert float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))) < 0.15     # converged again 1 s after the gap


def test_variance_growing_while_measurements_arrive_is_a_divergence(replay_core: Path) -> None:
    """Measurements that arrive but cannot bound P (5 s of ranges to anchor 0 only, 25 Hz: the directions
    across it are unobserved; their variance passes 10 m^2 within 2 s) still make the covariance bound a
    divergence, in C and twin alike."""
    flight = synthetic_flight(KIND_TWR, noise=0.05, duration_s=12.0, seed=11)
    u = flight.uwb
    flight = _uwb_where(flight, (u.t_us < 3_000_000) | (u.t_us >= 8_000_000) | (u.anchor_a == 0))
    cfg = replace(base_config(flight, MODE_UWB_ONLY), sup_max_var=10.0)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    t_flags = np.array([r.flags for r in twin])
    np.testing.assert_array_equal(c.flags, t_flags)
    assert c.divergences >= 1 and np.any(t_flags == FLAG_DIVERGED | FLAG_COVARIANCE)
    assert not np.any(t_flags & FLAG_GAP_RESTART)


def test_height_pseudo_measurements_match_twin(replay_core: Path) -> None:
    """Planar mode: HEIGHT frames before the measurements; C and twin fuse them identically."""
    flight = synthetic_flight(KIND_TWR, noise=0.1, outliers=True, seed=7)
    t = flight.uwb.t_us
    z = f32(flight.truth.pos[:, 2])
    flight = replace(flight, height=HeightStream(t_us=t, z=z, std=0.05))
    cfg = base_config(flight, MODE_UWB_ONLY)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    assert c.heights == len(t) and c.divergences == 0
    np.testing.assert_array_equal(c.status, [r.status for r in twin])
    np.testing.assert_array_equal(c.flags, [r.flags for r in twin])
    assert np.all(c.flags == FLAG_HEIGHT_FUSED)
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-4
    assert np.sqrt(np.mean((c.pos[:, 2] - flight.truth.pos[:, 2]) ** 2)) < 0.02


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
def test_robust_update_matches_twin_and_resists_outliers(replay_core: Path, mode: int) -> None:
    from harness.config import PRESETS, STAGE_ROBUST_UPDATE
    flight = synthetic_flight(KIND_TWR, noise=0.05, outliers=True, seed=9)
    cfg = replace(base_config(flight, mode, stages=PRESETS["robust"]), std_twr=0.1)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    assert_core_equals_twin(c, twin)
    # Without any gate, the +1 m (10 sigma) and -0.4 m outliers are all fused: the weights alone must keep
    # them from pulling the estimate, the C core as the twin.
    alone = replace(cfg, stages=STAGE_ROBUST_UPDATE)
    c_alone = run_c(replay_core, flight, alone)
    t_alone = np.array([r.pos for r in run_flight(flight, alone)])
    assert np.max(np.abs(c_alone.pos - t_alone)) < 1e-4
    no_rejection = rmse(np.array([r.pos for r in run_flight(flight, replace(cfg, stages=0))]), flight)
    assert rmse(c_alone.pos, flight) < 0.7 * no_rejection


def hover_with_vibrating_accelerometer(seed: int = 4) -> Flight:
    """A tag hovering at rest while its accelerometer reads a horizontal offset in flight, as a Crazyflie's does
    (vibration: -2 m/s^2 in x, -1 in y, with 2 m/s^2 of noise; docs/real-flights.md)."""
    rng = np.random.default_rng(seed)
    anchors = f32(box_anchors())
    t_imu = np.arange(0, 6_000_001, 1000, dtype=np.int64)
    acc = np.array([-2.0, -1.0, 9.81]) + 2.0 * rng.standard_normal((len(t_imu), 3)) * np.array([1.0, 1.0, 0.2])
    t_uwb = np.arange(2500, 6_000_000, 5000, dtype=np.int64)
    pos = np.tile([2.0, 1.5, 1.5], (len(t_uwb), 1))
    k = np.arange(len(t_uwb))
    a, b = k % 8, (k + 1) % 8
    true_value = np.linalg.norm(pos - anchors[b], axis=1) - np.linalg.norm(pos - anchors[a], axis=1)
    uwb = UwbStream(kind=KIND_TDOA, t_us=t_uwb, anchor_a=a, anchor_b=b,
                    value=f32(true_value + 0.05 * rng.standard_normal(len(k))), true_value=true_value)
    flight = Flight(name="hover-vibrating", anchors=Anchors(ids=np.arange(8), positions=anchors), uwb=uwb,
                    truth=Truth(t_us=t_uwb, pos=pos), imu=ImuStream(t_us=t_imu, acc=f32(acc),
                                                                     gyro=np.zeros((len(t_imu), 3))))
    flight.validate()
    return flight


def test_thrust_mode_ignores_horizontal_accelerometer(replay_core: Path) -> None:
    """IMU_THRUST (the quadrotor model) integrates body-z only: the vibration offset that tilts and pulls the
    full-accelerometer model leaves it at the truth; the C core and the twin agree in that mode."""
    flight = hover_with_vibrating_accelerometer()
    full = np.array([r.pos for r in run_flight(flight, base_config(flight, MODE_IMU))])
    twin = run_flight(flight, base_config(flight, MODE_IMU_THRUST))
    thrust = np.array([r.pos for r in twin])
    assert rmse(thrust, flight) < 0.03
    assert rmse(full, flight) > 1.3 * rmse(thrust, flight)

    def tilt_deg(results: list[TwinResult]) -> float:
        return max(2 * np.degrees(np.arccos(min(1.0, abs(r.quat[0])))) for r in results[-100:])
    assert tilt_deg(twin) < 2.0            # no attitude made up to explain the offset
    assert tilt_deg(run_flight(flight, base_config(flight, MODE_IMU))) > 4.0
    c = run_c(replay_core, flight, base_config(flight, MODE_IMU_THRUST))
    assert_core_equals_twin(c, twin)
