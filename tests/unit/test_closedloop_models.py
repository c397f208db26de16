"""Closed loop (issue 9) without a device: the vehicle model, sensors against the simulator's error model (the
NLOS profile's blocked links too), mission plans, the take-off rule and flight metrics, the loop's configuration
and the report section built from a fly result. The flights through the device are in
tests/device/test_closedloop.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.closedloop.cosim import FlightLog, LoopConfig
from harness.closedloop.metrics import TakeoffRule, aggregate, flight_metrics, takeoff
from harness.closedloop.mission import Mission, MissionError, plan
from harness.closedloop.sensors import LinkModel, SensorConfig, Sensors
from harness.closedloop.vehicle import GRAVITY, Vehicle, VehicleParams
from harness.flight.arena import NLOS_BOXES, Arena
from harness.flight.measurement_errors import hardware_params, range_bias, sim_config, uwb_errors
from harness.flight.data import KIND_TDOA

ARENA = Arena()


# ------------------------------------------------------------------------------------------ vehicle
def _hover_thrust(p: VehicleParams) -> float:
    return p.mass * GRAVITY


def test_vehicle_rests_on_the_ground_and_measures_gravity() -> None:
    v = Vehicle(VehicleParams(), pos=(1.0, 2.0, 0.0))
    assert v.state.pos == [1.0, 2.0, 0.05]            # the tag stands ground_z above the floor
    for _ in range(500):
        v.step(0.1, (1.0, 0.0, 0.0), 0.002)            # thrust below weight, a rate command: nothing moves
    assert v.state.pos == [1.0, 2.0, 0.05] and v.state.on_ground
    assert v.specific_force == (0.0, 0.0, GRAVITY) and v.tilt() == 0.0


def test_vehicle_hover_free_fall_and_thrust_limit() -> None:
    p = VehicleParams()
    v = Vehicle(p, pos=(0.0, 0.0, 1.0))
    v.state.on_ground = False
    v.state.motors = [_hover_thrust(p) / 4] * 4
    for _ in range(500):                               # 1 s at exactly the weight
        v.step(_hover_thrust(p), (0.0, 0.0, 0.0), 0.002)
    assert abs(v.state.pos[2] - 1.0) < 1e-9 and v.state.vel == [0.0, 0.0, 0.0]
    assert v.specific_force[2] == pytest.approx(GRAVITY, abs=1e-12)   # the IMU feels the thrust, not gravity
    v.state.motors = [0.0] * 4
    for _ in range(150):                               # 0.3 s of free fall
        v.step(0.0, (0.0, 0.0, 0.0), 0.002)
    assert v.state.pos[2] == pytest.approx(1.0 - 0.5 * GRAVITY * 0.3 ** 2, abs=0.01)
    # free fall: the accelerometer feels only the drag (the motors are off)
    assert v.specific_force[2] == pytest.approx(-p.drag[2] * v.state.vel[2] / p.mass, rel=0.01)  # v one step earlier
    assert 0.5 < v.specific_force[2] < 0.8
    # full thrust: bounded by 4 f_max, reached through the motor lag
    w = Vehicle(p, pos=(0.0, 0.0, 0.05))
    w.step(10.0, (0.0, 0.0, 0.0), 0.002)
    assert sum(w.state.motors) == pytest.approx(4 * p.f_max * 0.002 / p.tau_motor, rel=1e-9)
    for _ in range(1000):
        w.step(10.0, (0.0, 0.0, 0.0), 0.002)
    assert sum(w.state.motors) == pytest.approx(4 * p.f_max, rel=1e-6)
    assert w.specific_force[2] == pytest.approx((4 * p.f_max - p.drag[2] * w.state.vel[2]) / p.mass, rel=0.01)


def test_vehicle_rate_loop_tracks_and_mixer_sums() -> None:
    p = VehicleParams()
    v = Vehicle(p, pos=(0.0, 0.0, 1.0))
    v.state.on_ground = False
    v.state.motors = [_hover_thrust(p) / 4] * 4
    for _ in range(150):                               # 0.3 s of a 1 rad/s roll-rate command
        v.step(_hover_thrust(p), (1.0, 0.0, 0.0), 0.002)
    assert v.state.omega[0] == pytest.approx(1.0, abs=0.05)
    assert abs(v.state.omega[1]) < 0.01 and abs(v.state.omega[2]) < 0.01
    assert 0.15 < v.tilt() < 0.3                      # ~0.3 s at up to 1 rad/s
    # mixer: collective thrust preserved while it rolls
    assert sum(v.state.motors) == pytest.approx(_hover_thrust(p), rel=0.02)


def test_vehicle_params_are_checked() -> None:
    with pytest.raises(ValueError, match="cannot lift"):
        Vehicle(VehicleParams(mass=0.07))
    with pytest.raises(ValueError, match="mass"):
        VehicleParams(mass=0.5).validate()
    with pytest.raises(ValueError, match="tau_motor"):
        VehicleParams(tau_motor=0.0).validate()


# ------------------------------------------------------------------------------------------ sensors
def test_link_bias_equals_the_simulator_error_model() -> None:
    """The scalar per-step bias is measurement_errors's: TWR links and TDoA pairs, random poses."""
    cfg = sim_config("los")
    links = LinkModel(cfg, ARENA)
    hw = hardware_params(cfg.antenna, ARENA.anchors.ids)
    rng = np.random.default_rng(5)
    n = 64
    tags = rng.uniform((-3, -3.5, 0.05), (3, 3.5, 2.8), size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    a_ids = rng.integers(0, 8, n)
    b_ids = (a_ids + rng.integers(1, 8, n)) % 8
    anc = ARENA.anchors
    ref_twr = range_bias(cfg.antenna, hw, a_ids, anc.positions[a_ids], anc.orientations[a_ids], tags, q)
    ref_tdoa = uwb_errors(cfg, KIND_TDOA, ARENA, tags, q, a_ids, b_ids, np.random.default_rng(0)).bias
    from harness.closedloop.sensors import _rot
    for i in range(n):
        r = _rot(tuple(q[i]))
        ba, _, uta = links.link(int(a_ids[i]), tuple(tags[i]), r)
        bb, _, utb = links.link(int(b_ids[i]), tuple(tags[i]), r)
        assert ba == pytest.approx(ref_twr[i], abs=1e-9)
        tdoa = bb - ba + links.pair[(int(a_ids[i]), int(b_ids[i]))] + cfg.antenna.pair_att_k * (utb - uta)
        assert tdoa == pytest.approx(ref_tdoa[i], abs=1e-9)
    # multipath probability near the floor, as measurement_errors: p_base + p_ground exp(-z / h)
    nl = cfg.nlos
    assert links.multipath_probability((0.0, 0.0, 0.0)) == pytest.approx(nl.p_base + nl.p_ground)
    assert links.multipath_probability((0.0, 0.0, 1.0)) == pytest.approx(
        nl.p_base + nl.p_ground * math.exp(-1.0 / nl.h_ground))


def test_schedule_pairs_and_noise_kinds() -> None:
    sim = sim_config("los")
    s = Sensors(SensorConfig(mode="tdoa", noise="none"), sim, ARENA, seed=3, imu_dt=0.002)
    due = s.due(100_000)                               # 0.1 s at 400 Hz
    assert len(due) in (39, 40, 41)
    t = [d[1] for d in due]
    assert all(b >= a for a, b in zip(t, t[1:]))
    assert [s.anchors_of(k) for k in range(3)] == [(7, 0), (0, 1), (1, 2)]   # TDoA2 consecutive pairs
    tag = (0.5, -0.2, 1.0)
    u = s.measure(0, t[0], tag, (1.0, 0.0, 0.0, 0.0))
    assert u.value == u.true_value == pytest.approx(math.dist(tag, ARENA.anchors.position(0))
                                                    - math.dist(tag, ARENA.anchors.position(7)))
    assert s.imu((0.0, 0.0, 9.81), (0.1, 0.0, 0.0)) == ((0.0, 0.0, 9.81), (0.1, 0.0, 0.0))
    g = Sensors(SensorConfig(mode="twr", noise="gaussian", noise_std=0.1), sim, ARENA, seed=3, imu_dt=0.002)
    assert g.cfg.uwb_rate() == 200.0 and g.anchors_of(9) == (1, -1)
    err = np.array([g.measure(k, 0, tag, (1.0, 0.0, 0.0, 0.0)).value - math.dist(tag, ARENA.anchors.position(k % 8))
                    for k in range(4000)])
    assert abs(np.mean(err)) < 0.01 and np.std(err) == pytest.approx(0.1, rel=0.05)
    # IMU white noise: the 1 kHz figure, averaged down to the frame rate
    imu = np.array([g.imu((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))[0] for _ in range(4000)])
    assert np.std(imu - imu.mean(axis=0), axis=0) == pytest.approx(
        [sim.imu.acc_noise * math.sqrt(0.5)] * 3, rel=0.1)
    with pytest.raises(ValueError, match="mode"):
        SensorConfig(mode="uwb").validate()
    with pytest.raises(ValueError, match="rate"):
        SensorConfig(rate_hz=0.5).validate()


def test_realistic_measurements_near_the_floor_see_more_multipath() -> None:
    sim = sim_config("los")
    s = Sensors(SensorConfig(mode="twr"), sim, ARENA, seed=1, imu_dt=0.002)
    low = sum(s.measure(k, 0, (0.0, 0.0, 0.05), (1.0, 0.0, 0.0, 0.0)).nlos for k in range(20000))
    high = sum(s.measure(k, 0, (0.0, 0.0, 1.5), (1.0, 0.0, 0.0, 0.0)).nlos for k in range(20000))
    nl = sim.nlos
    assert low / 20000 == pytest.approx(nl.p_base + nl.p_ground * math.exp(-0.05 / nl.h_ground), rel=0.25)
    assert high < low / 3


# ------------------------------------------------------------------------------------------ mission
def test_mission_plan_phases_and_speed() -> None:
    pl = plan(Mission(name="circle", laps=1.0), ARENA)
    ms = pl.mission
    assert pl.t_takeoff == ms.ground_wait_s and pl.t_main0 == ms.ground_wait_s + ms.takeoff_s
    assert pl.start == pytest.approx((2.0, 0.0, 0.05))
    assert not pl.motors_on[0] and pl.motors_on[np.searchsorted(pl.t, pl.t_takeoff)]
    assert not pl.motors_on[-1]
    main = (pl.t > pl.t_main0 + ms.ramp_s + 0.1) & (pl.t < pl.t_main1 - ms.ramp_s - 0.1)
    speed = np.linalg.norm(pl.vel[main], axis=1)
    assert speed == pytest.approx(np.full(speed.shape, 0.375), abs=1e-4)
    assert np.linalg.norm(pl.pos[main, :2], axis=1) == pytest.approx(np.full(speed.shape, 2.0), abs=1e-6)
    # one full lap: it comes back to where it started
    end = np.searchsorted(pl.t, pl.t_main1)
    assert np.linalg.norm(pl.pos[end, :2] - pl.pos[np.searchsorted(pl.t, pl.t_main0), :2]) < 1e-3
    cz = plan(Mission(name="circle-z"), ARENA)
    assert np.ptp(cz.pos[(cz.t > cz.t_main0) & (cz.t < cz.t_main1), 2]) == pytest.approx(1.2, abs=0.05)
    with pytest.raises(MissionError, match="leaves the arena"):
        plan(Mission(name="circle", radius=3.8), ARENA)
    with pytest.raises(MissionError, match="unknown mission"):
        plan(Mission(name="figure8"), ARENA)
    # the nlos arena's obstacles stand in the way of the 2 m circle; 1.5 m flies around them
    with pytest.raises(MissionError, match="passes through the obstacle"):
        plan(Mission(name="circle"), Arena(boxes=NLOS_BOXES))
    assert plan(Mission(name="circle", radius=1.5), Arena(boxes=NLOS_BOXES)).duration > 30.0


# ------------------------------------------------------------------------------------------ metrics
def _synthetic_log(z_of_t, tilt_rad: float = 0.0, drift: float = 0.0) -> FlightLog:  # noqa: ANN001
    t = np.arange(0, 8.0, 0.01)
    n = len(t)
    p_true = np.zeros((n, 3))
    p_true[:, 2] = [z_of_t(x) for x in t]
    p_true[:, 0] = drift
    p_cmd = np.zeros((n, 3))
    p_cmd[:, 2] = p_true[:, 2]
    q = np.tile([math.cos(tilt_rad / 2), math.sin(tilt_rad / 2), 0.0, 0.0], (n, 1))
    log = FlightLog(t=t, p_true=p_true, v_true=np.zeros((n, 3)), q_true=q, p_cmd=p_cmd, p_est=p_true + 0.1,
                    v_est=np.zeros((n, 3)), q_est=q, thrust=np.zeros(n), rates=np.zeros((n, 3)),
                    flags=np.zeros(n, np.uint8), motors_on=np.ones(n, bool), ctl_on=np.ones(n, bool),
                    compute=np.zeros(n, np.uint32), statuses={}, nlos_events=0)
    log.meta = {"phases": {"t_takeoff": 2.0, "t_main0": 5.0, "t_main1": 6.0, "t_land": 7.0}}
    return log


def test_takeoff_rule_and_flight_metrics() -> None:
    climb = lambda t: 0.05 if t < 2.0 else min(1.2, 0.05 + 0.5 * (t - 2.0))   # noqa: E731
    ok = takeoff(_synthetic_log(climb))
    assert ok["success"] and ok["t_reach_s"] == pytest.approx(0.9, abs=0.011)
    slow = takeoff(_synthetic_log(lambda t: 0.05 if t < 2.0 else 0.05 + 0.1 * (t - 2.0)))
    assert not slow["success"] and "did not reach 0.5 m within 3.0 s" in slow["reason"]
    tilted = takeoff(_synthetic_log(climb, tilt_rad=math.radians(40)))
    assert not tilted["success"] and "tilt 40 deg" in tilted["reason"]
    drifted = takeoff(_synthetic_log(climb, drift=0.8), TakeoffRule(max_drift_m=0.5))
    assert not drifted["success"] and "drift" in drifted["reason"]
    fm = flight_metrics(_synthetic_log(climb, drift=0.03))
    assert fm["tracking_rmse"] == pytest.approx(0.03) and fm["estimation_rmse"] == pytest.approx(0.1 * math.sqrt(3))
    agg = aggregate([_synthetic_log(climb, drift=0.03), _synthetic_log(climb, drift=0.05)],
                    [fm, flight_metrics(_synthetic_log(climb, drift=0.05))])
    assert agg["takeoff_success"] == 2 and agg["tracking_rmse_mean"] == pytest.approx(0.04)
    k = agg["series"]["t"].index(3.0)
    assert agg["series"]["rmse"][k] == pytest.approx(math.sqrt((0.03 ** 2 + 0.05 ** 2) / 2), abs=1e-4)


def test_loop_config_is_checked() -> None:
    with pytest.raises(ValueError, match="pacing"):
        LoopConfig(pacing="fast").validate()
    with pytest.raises(ValueError, match="whole number"):
        LoopConfig(physics_dt=0.003).validate()
    with pytest.raises(ValueError, match="imu_every"):
        LoopConfig(imu_every=3).validate()


def test_nlos_profile_blocked_links_are_delayed() -> None:
    sim = sim_config("nlos")
    arena = Arena(boxes=NLOS_BOXES)
    s = Sensors(SensorConfig(mode="twr"), sim, arena, seed=2, imu_dt=0.002)
    tag = (-2.7, 0.0, 0.5)          # just behind the first box (x -2.6..-1.8): anchors at x = +3.5 are hidden
    blocked = [a for a in range(8) if s.links.blocked(a, tag, arena)]
    clear = [a for a in range(8) if a not in blocked]
    assert blocked and clear
    level = (1.0, 0.0, 0.0, 0.0)
    from harness.closedloop.sensors import _rot

    def mean_excess(anchor: int) -> float:
        """Mean of measured - true - pose bias: the multipath / penetration excess (plus zero-mean noise)."""
        k0 = s.ids.index(anchor)
        bias = s.links.link(anchor, tag, _rot(level))[0] + sim.twr_offset
        return float(np.mean([s.measure(k0 + 8 * j, 0, tag, level).value
                              - math.dist(tag, arena.anchors.position(anchor)) - bias for j in range(1000)]))
    nl = sim.nlos
    p_mp = s.links.multipath_probability(tag)
    assert mean_excess(clear[0]) == pytest.approx(p_mp * nl.mean_m, abs=0.01)
    assert mean_excess(blocked[0]) == pytest.approx(p_mp * nl.mean_m + nl.p_block * (nl.block_delay_m + nl.block_mean_m),
                                                    abs=0.03)


def test_report_section_from_a_fly_result(tmp_path) -> None:  # noqa: ANN001
    from harness.closedloop.cli import markdown_table
    from harness.report.closed_loop import RESULT_NAME, closed_loop_section
    climb = lambda t: 0.05 if t < 2.0 else min(1.2, 0.05 + 0.5 * (t - 2.0))   # noqa: E731
    logs = [_synthetic_log(climb, drift=d) for d in (0.03, 0.05)]
    per = [flight_metrics(lg) for lg in logs]
    cell = {"mode": "tdoa", "mission": "circle", "config": "outlier+nn", **aggregate(logs, per), "per_flight": per}
    result = {"cells": [cell], "spec": {"seeds": [1, 2], "profile": "los"}}
    assert "| tdoa | circle | outlier+nn | 2/2 | 2/2 | 0.040 +- 0.010 |" in markdown_table(result)
    import json
    (tmp_path / RESULT_NAME).write_text(json.dumps(result))

    class Ctx:
        fig_dir = tmp_path / "figures"

        def figure(self, fig, name, caption):  # noqa: ANN001, ANN201
            from harness.report import plots
            from harness.report.html import FigureRef
            return [FigureRef(plots.save(fig, self.fig_dir / f"{name}.png"), caption)]

    sec = closed_loop_section(Ctx())
    assert sec is not None and sec.tables[0].rows[0][:5] == ["tdoa", "circle", "outlier+nn", "2/2", "2/2"]
    assert sec.figures and sec.figures[0].path.is_file()
    assert closed_loop_section(type("Empty", (), {"fig_dir": tmp_path / "none" / "figures"})()) is None
