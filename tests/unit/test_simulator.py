"""The flight simulator: reproducibility, IMU consistent with the trajectory, rates and pair patterns,
error-model structure (attitude-dependent bias, NLOS near the ground and behind obstacles, TDoA noisier
than TWR), constellation files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from constellation_yaml import save_constellation_yaml
from harness.flight.arena import Arena, Box, ConstellationError, default_anchors, load_constellation
from harness.flight.measurement_errors import sim_config, uwb_errors
from harness.flight.data import KIND_TDOA, KIND_TWR
from harness.flight.scenarios import SCENARIOS, ScenarioError, scenario_flight
from harness.flight.trajectory import GRAVITY, quat_to_rot


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def test_same_seed_same_arrays_other_seed_other_noise() -> None:
    a = scenario_flight("random", mode="tdoa", duration_s=8.0, seed=5)
    b = scenario_flight("random", mode="tdoa", duration_s=8.0, seed=5)
    c = scenario_flight("random", mode="tdoa", duration_s=8.0, seed=6)
    for x, y in ((a.uwb.value, b.uwb.value), (a.uwb.t_us, b.uwb.t_us), (a.imu.acc, b.imu.acc),
                 (a.imu.gyro, b.imu.gyro), (a.truth.pos, b.truth.pos), (a.truth.quat, b.truth.quat)):
        assert np.array_equal(x, y)
    assert not np.array_equal(a.uwb.value, c.uwb.value)
    assert not np.array_equal(a.truth.pos, c.truth.pos)      # random trajectories differ per seed
    assert a.meta["scenario"] == "random" and a.meta["seed"] == 5 and a.meta["profile"] == "los"
    assert "sim_config" in a.meta


@pytest.mark.parametrize("name", SCENARIOS)
def test_truth_covers_measurements_and_noiseless_values_are_exact(name: str) -> None:
    f = scenario_flight(name, mode="twr", duration_s=10.0, seed=2, noise="none")
    u = f.uwb
    assert f.truth.t_us[0] <= u.t_us[0] and u.t_us[-1] <= f.truth.t_us[-1]
    assert np.array_equal(u.value, u.true_value)
    p = f.truth.position_at(u.t_us)
    ranges = np.linalg.norm(p - np.stack([f.anchors.position(int(i)) for i in u.anchor_a]), axis=1)
    assert np.max(np.abs(ranges - u.true_value)) < 1e-4       # 1 kHz truth, linear interpolation
    assert f.truth.quat is not None and f.truth.vel is not None
    assert np.allclose(np.linalg.norm(f.truth.quat, axis=1), 1.0)


@pytest.mark.parametrize("name", ["circle-z", "random", "spin"])
def test_integrating_the_imu_reproduces_the_trajectory(name: str) -> None:
    """Strapdown integration of the noiseless IMU (quaternion from gyro, world acc = R f - g) over 2 s windows
    stays on the true path: the IMU is the trajectory's own specific force and body rate."""
    f = scenario_flight(name, mode="twr", duration_s=20.0, seed=3, noise="none")
    imu, truth = f.imu, f.truth
    dt = 1e-3
    for start in (3000, 9000, 15000):
        q = truth.quat[start].copy()
        p = truth.pos[start].copy()
        v = truth.vel[start].copy()
        for k in range(start, start + 2000):
            # midpoint rule: average of the samples at k and k+1
            w = 0.5 * (imu.gyro[k] + imu.gyro[k + 1])
            r0 = quat_to_rot(q[None, :])[0]
            ang = np.linalg.norm(w) * dt
            axis = w / np.linalg.norm(w) if ang > 0 else np.zeros(3)
            q1 = _quat_mul(q, np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis]))
            q1 /= np.linalg.norm(q1)
            r1 = quat_to_rot(q1[None, :])[0]
            a0 = r0 @ imu.acc[k] - np.array([0, 0, GRAVITY])
            a1 = r1 @ imu.acc[k + 1] - np.array([0, 0, GRAVITY])
            p = p + v * dt + (a0 / 3 + a1 / 6) * dt * dt
            v = v + 0.5 * (a0 + a1) * dt
            q = q1
        end = start + 2000
        assert np.linalg.norm(p - truth.pos[end]) < 5e-3, name
        assert np.linalg.norm(v - truth.vel[end]) < 5e-3, name
        assert abs(abs(float(np.dot(q, truth.quat[end]))) - 1.0) < 1e-6, name


def test_gravity_sign_and_takeoff_landing() -> None:
    f = scenario_flight("hover", mode="twr", duration_s=30.0, seed=1, noise="none", takeoff=True)
    # resting on the ground and hovering: the accelerometer reads +g along body z (specific force up)
    assert np.allclose(f.imu.acc[0], [0.0, 0.0, GRAVITY], atol=1e-6)
    assert np.allclose(f.imu.gyro[0], 0.0, atol=1e-9)
    assert f.truth.pos[0, 2] == pytest.approx(0.05) and f.truth.pos[-1, 2] == pytest.approx(0.05)
    assert np.max(f.truth.pos[:, 2]) == pytest.approx(1.2, abs=1e-9)
    mid = len(f.imu) // 2
    assert np.allclose(f.imu.acc[mid], [0.0, 0.0, GRAVITY], atol=1e-4)
    # during the climb the specific force exceeds g (accelerating up), then drops below it
    climb = f.imu.acc[1000:5000, 2]
    assert climb.max() > GRAVITY + 0.05 and climb.min() < GRAVITY - 0.05


def test_circle_speed_tilt_and_spin_yaw_rate() -> None:
    f = scenario_flight("circle", mode="twr", duration_s=40.0, seed=1, noise="none")
    speed = np.linalg.norm(f.truth.vel, axis=1)
    assert speed[0] == pytest.approx(0.0, abs=1e-6)
    assert np.median(speed) == pytest.approx(0.375, abs=1e-4)
    # centripetal acceleration v^2/r = 0.07 m/s^2 -> tilt atan(0.07/9.81) = 0.41 deg, towards the centre
    att = f.truth.attitude_at(f.truth.t_us[20000:20001])[0]
    tilt = np.degrees(np.hypot(att[0], att[1]))
    assert tilt == pytest.approx(np.degrees(np.arctan(0.375 ** 2 / 2.0 / GRAVITY)), abs=0.02)
    s = scenario_flight("spin", mode="twr", duration_s=30.0, seed=1, noise="none", spin_dps=45.0)
    assert np.median(s.imu.gyro[:, 2]) == pytest.approx(np.radians(45.0), rel=1e-4)
    assert np.allclose(s.truth.pos, s.truth.pos[0], atol=1e-9)


def test_twr_round_robin_tdoa2_consecutive_pairs_tdoa3_random_pairs() -> None:
    twr = scenario_flight("circle", mode="twr", duration_s=10.0, seed=1)
    ids = twr.anchors.ids
    assert list(twr.uwb.anchor_a[:16]) == list(ids) * 2
    assert np.all(twr.uwb.anchor_b == -1) and twr.uwb.kind == KIND_TWR
    tdoa = scenario_flight("circle", mode="tdoa", duration_s=10.0, seed=1)
    pairs = list(zip(tdoa.uwb.anchor_a[:8].tolist(), tdoa.uwb.anchor_b[:8].tolist()))
    assert pairs == [(7, 0), (0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7)]
    assert tdoa.uwb.kind == KIND_TDOA
    t3 = scenario_flight("circle", mode="tdoa3", duration_s=10.0, seed=1)
    a, b = t3.uwb.anchor_a, t3.uwb.anchor_b
    assert np.all(a != b)
    assert len(set(zip(a.tolist(), b.tolist()))) == 56      # every ordered pair of 8 anchors appears
    for f in (twr, tdoa, t3):
        rate = len(f.uwb) / (f.uwb.t_us[-1] - f.uwb.t_us[0]) * 1e6
        assert 200.0 <= rate <= 500.0
        assert np.all(np.diff(f.uwb.t_us) > 0)
    fast = scenario_flight("circle", mode="twr", duration_s=10.0, seed=1, rate_hz=400.0)
    assert len(fast.uwb) == pytest.approx(2 * len(twr.uwb), abs=2)


def _errors(kind: int, arena: Arena, pos: np.ndarray, quat: np.ndarray, a: np.ndarray, b: np.ndarray,
            cfg=None, seed: int = 0):  # noqa: ANN001, ANN202
    return uwb_errors(cfg or sim_config("los"), kind, arena, pos, quat, a, b, np.random.default_rng(seed))


def test_nlos_rate_grows_near_the_ground_and_behind_obstacles() -> None:
    n = 40000
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    a = np.full(n, 2)
    b = np.full(n, -1)
    cfg = sim_config("nlos")
    open_arena = Arena()
    high = np.tile([0.0, 0.0, 1.5], (n, 1))
    low = np.tile([0.0, 0.0, 0.05], (n, 1))
    e_high = _errors(KIND_TWR, open_arena, high, quat, a, b, cfg)
    e_low = _errors(KIND_TWR, open_arena, low, quat, a, b, cfg)
    assert e_low.nlos_flag.mean() > 2.0 * e_high.nlos_flag.mean() > 0.0
    # a box between the tag and anchor 2 (at (3.5, 4, 0.15)): the link is delayed, others are not
    box = Box((1.0, 1.0, 0.0), (2.0, 2.0, 2.0))
    blocked = Arena(boxes=(box,))
    assert blocked.blocked(high[:1], default_anchors().position(2)[None, :])[0]
    e_box = _errors(KIND_TWR, blocked, high, quat, a, b, cfg)
    assert e_box.nlos_flag.mean() > 0.9
    assert np.median(e_box.nlos) >= cfg.nlos.block_delay_m
    e_other = _errors(KIND_TWR, blocked, high, quat, np.full(n, 0), b, cfg)   # anchor 0 is not behind the box
    assert e_other.nlos_flag.mean() == pytest.approx(e_high.nlos_flag.mean(), abs=0.01)
    # multipath errors are positive on a link; a TDoA sees B's excess with +, A's with -
    assert np.all(e_box.nlos >= 0.0)
    e_tdoa = _errors(KIND_TDOA, blocked, high, quat, np.full(n, 0), np.full(n, 2), cfg)
    assert np.median(e_tdoa.nlos[e_tdoa.nlos != 0]) > 0.0
    e_tdoa_rev = _errors(KIND_TDOA, blocked, high, quat, np.full(n, 2), np.full(n, 0), cfg)
    assert np.median(e_tdoa_rev.nlos[e_tdoa_rev.nlos != 0]) < 0.0


def test_bias_depends_on_attitude_spin_changes_twr_error() -> None:
    """Spinning in place changes only the yaw; the TWR bias to each anchor varies with it (antenna
    pattern of the tag), by a learnable amount well above the clock quantisation."""
    spin = scenario_flight("spin", mode="twr", duration_s=30.0, seed=4, noise="none")
    u = spin.uwb
    quat = spin.truth.quat_at(u.t_us)
    pos = spin.truth.position_at(u.t_us)
    e = _errors(KIND_TWR, Arena(), pos, quat, u.anchor_a, u.anchor_b)
    level = np.tile([1.0, 0.0, 0.0, 0.0], (len(u), 1))
    e_fixed = _errors(KIND_TWR, Arena(), pos, level, u.anchor_a, u.anchor_b)
    for aid in spin.anchors.ids:
        m = u.anchor_a == aid
        assert np.ptp(e.bias[m]) > 0.04, aid          # varies over a revolution
        assert np.ptp(e_fixed.bias[m]) < 1e-12        # same pose, same bias: deterministic, not noise
    # the bias is a function of the pose, independent of the flight seed (same radios in every flight)
    e2 = _errors(KIND_TWR, Arena(), pos, quat, u.anchor_a, u.anchor_b, seed=99)
    assert np.array_equal(e.bias, e2.bias) and not np.array_equal(e.noise, e2.noise)


def test_tdoa_noisier_than_twr_and_bias_comparable_to_noise() -> None:
    cfg = sim_config("los")
    assert cfg.tdoa_std > cfg.twr_std
    twr = scenario_flight("random", mode="twr", duration_s=30.0, seed=8)
    tdoa = scenario_flight("random", mode="tdoa", duration_s=30.0, seed=8)

    def white(f) -> float:  # noqa: ANN001
        e = f.uwb.value - f.uwb.true_value
        d = np.concatenate([np.diff(e[(f.uwb.anchor_a == a) & (f.uwb.anchor_b == b)])
                            for a, b in set(zip(f.uwb.anchor_a.tolist(), f.uwb.anchor_b.tolist()))])
        return float(np.std(d[np.abs(d) < 0.5]) / np.sqrt(2))

    assert white(tdoa) > 1.2 * white(twr)
    assert white(tdoa) == pytest.approx(cfg.tdoa_std, rel=0.1)
    u = tdoa.uwb
    e = _errors(KIND_TDOA, Arena(), tdoa.truth.position_at(u.t_us), tdoa.truth.quat_at(u.t_us), u.anchor_a,
                u.anchor_b)
    # the learnable part is a substantial share: its std is at least the noise std
    assert np.std(e.bias) >= cfg.tdoa_std


def test_noise_kinds_and_gaussian_std() -> None:
    g = scenario_flight("circle", mode="tdoa", duration_s=20.0, seed=3, noise="gaussian", noise_std=0.2)
    e = g.uwb.value - g.uwb.true_value
    assert np.std(e) == pytest.approx(0.2, rel=0.05) and abs(np.mean(e)) < 0.01
    r = scenario_flight("circle", mode="twr", duration_s=20.0, seed=3)
    q = r.meta["sim_config"]["quantum_m"]
    assert np.allclose(r.uwb.value / q, np.round(r.uwb.value / q), atol=1e-6)   # clock quantisation
    n = scenario_flight("circle", mode="twr", duration_s=20.0, seed=3, profile="nlos")
    assert n.meta["profile"] == "nlos" and n.meta["obstacles"]
    cfg = replace(sim_config("los"), twr_std=0.0, antenna=replace(sim_config().antenna, hardware_seed=7))
    c = scenario_flight("circle", mode="twr", duration_s=20.0, seed=3, config=cfg)
    assert c.meta["sim_config"]["antenna"]["hardware_seed"] == 7


def test_bad_arguments_raise_clear_errors() -> None:
    with pytest.raises(ScenarioError, match="unknown scenario"):
        scenario_flight("loop", mode="twr")
    with pytest.raises(ScenarioError, match="unknown mode"):
        scenario_flight("circle", mode="aoa")
    with pytest.raises(ScenarioError, match="unknown noise"):
        scenario_flight("circle", noise="pink")
    with pytest.raises(ScenarioError, match="unknown option"):
        scenario_flight("circle", duration_s=5.0, radius_m=3.0)
    with pytest.raises(ScenarioError, match="too short"):
        scenario_flight("circle", duration_s=10.0, takeoff=True)
    with pytest.raises(ValueError, match="unknown simulator profile"):
        scenario_flight("circle", profile="outdoor")
    for bad in (float("nan"), -1.0):
        with pytest.raises(ScenarioError):
            scenario_flight("circle", duration_s=bad)


def test_constellation_files_round_trip_and_errors(tmp_path: Path) -> None:
    anchors = default_anchors()
    assert anchors.orientations is not None
    # each antenna's x axis points at the arena centre
    x_axes = quat_to_rot(anchors.orientations)[:, :, 0]
    to_center = Arena().center[None, :] - anchors.positions
    assert np.allclose(x_axes, to_center / np.linalg.norm(to_center, axis=1, keepdims=True))
    y = tmp_path / "c.yaml"
    save_constellation_yaml(anchors, y)
    back = load_constellation(y)
    assert np.array_equal(back.ids, anchors.ids)
    assert np.allclose(back.positions, anchors.positions, atol=1e-6)
    assert np.allclose(back.orientations, anchors.orientations, atol=1e-8)
    c = tmp_path / "a.csv"
    c.write_text("constellation,anchor_id,x_m,y_m,z_m\n1,0,0,0,0\n1,1,4,0,0\n2,0,1,1,1\n2,1,2,2,2\n1,2,0,4,2\n")
    one = load_constellation(c, constellation=1)
    assert list(one.ids) == [0, 1, 2] and one.orientations is not None
    with pytest.raises(ConstellationError, match="say which one"):
        load_constellation(c)
    bad = tmp_path / "bad.csv"
    bad.write_text("constellation,anchor_id,x_m,y_m,z_m\n1,0,0,0,0\n1,1,abc,0,0\n")
    with pytest.raises(ConstellationError, match=r"bad.csv:3: field x_m"):
        load_constellation(bad)
    bady = tmp_path / "bad.yaml"
    bady.write_text("anchors:\n  - {id: 0, position: [0, 0]}\n")
    with pytest.raises(ConstellationError, match=r"bad.yaml:2: field position needs 3"):
        load_constellation(bady)
    with pytest.raises(ConstellationError, match="not found"):
        load_constellation(tmp_path / "missing.csv")
    f = scenario_flight("circle", mode="tdoa", duration_s=8.0, seed=1, anchors=back)
    assert f.anchors is back


def test_attitude_at_interpolates_quaternions() -> None:
    f = scenario_flight("spin", mode="twr", duration_s=20.0, seed=1, noise="none")
    t = f.truth.t_us[5000:5002]
    mid = np.array([(t[0] + t[1]) // 2])
    yaw = f.truth.attitude_at(np.concatenate([t[:1], mid, t[1:]]))[:, 2]
    assert yaw[0] < yaw[1] < yaw[2]
    assert f.truth.attitude_at(f.truth.t_us[:1])[0] == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
