"""The numpy twin on its own: equations against hand numbers, finite differences and invariants."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from harness.config import (MODE_IMU, MODE_UWB_ONLY, STAGE_BIAS_NN, STAGE_CHI2_GATE, STAGE_KINEMATIC_GATE,
                            EstimatorConfig, ConfigError)
from harness.flight.data import KIND_TWR, Anchors, Flight, ImuStream, Truth, UwbStream
from harness import kinds as measurements
from harness.twin import gates
from harness.twin.ekf import GRAVITY, INIT_STD_ATT, INIT_STD_VEL, P_MAX, P_MIN, ErrorStateEkf, quat_to_rpy, sym_clamp
from harness.twin.estimator import (ACCEPTED, ERR_BAD_ANCHOR_ID, ERR_TIME_BACKWARDS, ERR_UNKNOWN_ANCHOR,
                                    REJECTED_CHI2, REJECTED_GEOMETRY, REJECTED_KINEMATIC, TwinError, TwinEstimator,
                                    run_flight)
from harness.twin.features import (LAYOUT_TDOA_POS, LAYOUT_TDOA_POSE, LAYOUT_TWR_POS, LAYOUT_TWR_POSE, features,
                                   layout_inputs)

ANCHORS = {i: np.array([3.5 if i & 1 else -3.5, 4.0 if i & 2 else -4.0, 3.0 if i & 4 else 0.0]) for i in range(8)}
STILL = np.array([0.0, 0.0, GRAVITY])
NO_GYRO = np.zeros(3)


def config(**kw: float) -> EstimatorConfig:
    return replace(EstimatorConfig(), **kw)


def rng_spd(rng: np.random.Generator) -> np.ndarray:
    L = np.tril(rng.uniform(-0.5, 0.5, (9, 9)))
    return L @ L.T + 0.01 * np.eye(9)


# ------------------------------------------------------------------------------------ ekf
def test_scalar_update_hand_computed() -> None:
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    ekf.P = np.diag([1.0, 2.0, 3.0, 0.5, 0.5, 0.5, 1e-4, 1e-4, 1e-4])
    ekf.P[0, 3] = ekf.P[3, 0] = 0.2
    u = ekf.prepare(np.array([0.6, 0.8, 0.0]), 0.5, 0.25)
    assert u.S == pytest.approx(1.89)
    assert u.mahalanobis == pytest.approx(0.5 / np.sqrt(1.89))
    ekf.apply(u)
    assert u.K[:4] == pytest.approx([0.6 / 1.89, 1.6 / 1.89, 0.0, 0.12 / 1.89])
    assert ekf.x[:2] == pytest.approx([0.3 / 1.89, 0.8 / 1.89])
    assert ekf.P[0, 0] == pytest.approx(1 - 0.36 / 1.89)
    assert ekf.P[0, 1] == pytest.approx(-0.96 / 1.89)
    assert ekf.P[0, 3] == pytest.approx(0.2 - 0.072 / 1.89)


def test_joseph_equals_optimal_form_and_stays_psd() -> None:
    rng = np.random.default_rng(0)
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    ekf.P = rng_spd(rng)
    for _ in range(500):
        h3 = rng.uniform(-1, 1, 3)
        u = ekf.prepare(h3, rng.uniform(-0.01, 0.01), 1e-4)
        expected = ekf.P - np.outer(u.PHT, u.PHT) / u.S
        ekf.apply(u)
        np.testing.assert_array_equal(ekf.P, ekf.P.T)
        assert np.all(np.diagonal(ekf.P) >= P_MIN)
        assert np.min(np.linalg.eigvalsh(ekf.P)) > -1e-12
        # Joseph == P - P H^T H P / S for the optimal gain (off the diagonal, which has a floor)
        assert np.max(np.abs(ekf.P - expected)[~np.eye(9, dtype=bool)]) < 1e-9


def test_sym_clamp() -> None:
    P = np.zeros((9, 9))
    P[0, 1], P[1, 0] = 1.0, 3.0
    P[2, 3] = np.nan
    P[4, 5] = P[5, 4] = 1e9
    P[6, 7] = P[7, 6] = -1e9
    P[8, 8] = -5.0
    P[3, 3] = np.inf
    S = sym_clamp(P)
    assert S[0, 1] == S[1, 0] == 2.0
    assert S[2, 3] == S[3, 2] == 0.0 and S[3, 3] == P_MAX   # a non-finite variance loses its correlations
    assert S[4, 5] == P_MAX and S[6, 7] == -P_MAX
    assert S[8, 8] == P_MIN and S[0, 0] == P_MIN


def test_sym_clamp_keeps_positive_definite() -> None:
    """Regression (rcv_twr sequence 3): clamping entry by entry left P indefinite, S < 0 and the state
    was thrown 1e5 m away. A variance above P_MAX now scales its row and column (a congruence)."""
    P = np.eye(9)
    P[2, 2], P[5, 5], P[2, 5], P[5, 2], P[0, 2], P[2, 0] = 1000.0, 400.0, 400.0, 400.0, 20.0, 20.0
    assert np.all(np.linalg.eigvalsh(P) > 0)
    old = np.clip(P, -P_MAX, P_MAX)              # what the entry-wise clamp did
    assert np.min(np.linalg.eigvalsh(old)) < 0
    S = sym_clamp(P)
    assert np.all(np.linalg.eigvalsh(S) > 0)
    assert S[2, 2] == pytest.approx(P_MAX) and S[5, 5] == pytest.approx(P_MAX)
    assert S[2, 5] / np.sqrt(S[2, 2] * S[5, 5]) == pytest.approx(400.0 / np.sqrt(1000.0 * 400.0))


def test_imu_prediction_covariance_at_rest() -> None:
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 2.0)
    dt, v, a = 0.01, INIT_STD_VEL**2, INIT_STD_ATT**2
    ekf.predict_imu(STILL, NO_GYRO, dt, 0.5, 1.0)
    assert ekf.x == pytest.approx(np.zeros(9), abs=1e-12)
    assert ekf.P[0, 0] == pytest.approx(1 + dt * dt * v + 0.25 * dt**3 / 3)
    assert ekf.P[2, 2] == pytest.approx(4 + dt * dt * v + dt**3 / 3)
    assert ekf.P[0, 3] == pytest.approx(dt * v + 0.25 * dt**2 / 2)
    assert ekf.P[3, 3] == pytest.approx(v + GRAVITY**2 * dt**2 * a + 0.25 * dt)
    assert ekf.P[3, 7] == pytest.approx(GRAVITY * dt * a)
    assert ekf.P[4, 6] == pytest.approx(-GRAVITY * dt * a)


def test_imu_integration_and_rotation() -> None:
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    for _ in range(100):
        ekf.predict_imu(np.array([1.0, 0.0, GRAVITY]), NO_GYRO, 0.01, 0.0, 0.0)
    assert ekf.x[3] == pytest.approx(1.0) and ekf.x[0] == pytest.approx(0.5) and ekf.x[2] == pytest.approx(0.0)
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    for _ in range(100):
        ekf.predict_imu(STILL, np.array([0.0, 0.0, 1.0]), 0.01, 0.0, 0.0)
    assert quat_to_rpy(ekf.q) == pytest.approx([0.0, 0.0, 1.0])


def test_imu_sample_timing() -> None:
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    assert not ekf.imu_sample(5000, STILL, NO_GYRO, 0.5, 1.0)  # first: time only
    assert ekf.t_us == 5000 and ekf.imu_count == 0
    assert not any(ekf.imu_sample(t, STILL, NO_GYRO, 0.5, 1.0) for t in range(6000, 15000, 1000))
    assert ekf.imu_sample(15000, STILL, NO_GYRO, 0.5, 1.0)
    assert ekf.t_us == 15000 and ekf.imu_count == 0


def test_cv_prediction() -> None:
    ekf = ErrorStateEkf.initial(np.array([1.0, 2.0, 3.0]), 1.0, 1.0)
    ekf.x[3], ekf.x[5] = 1.0, -2.0
    ekf.predict_cv(2.0, 0.1)
    v = INIT_STD_VEL**2
    assert ekf.x[:3] == pytest.approx([1.1, 2.0, 2.8])
    assert ekf.P[0, 0] == pytest.approx(1 + 0.01 * v + 4 * 0.001 / 3)
    assert ekf.P[0, 3] == ekf.P[3, 0] == pytest.approx(0.1 * v + 4 * 0.01 / 2)
    assert ekf.P[3, 3] == pytest.approx(v + 0.4)


def test_finalize() -> None:
    ekf = ErrorStateEkf.initial(np.zeros(3), 1.0, 1.0)
    ekf.x[8] = 0.1
    ekf.finalize()
    assert quat_to_rpy(ekf.q)[2] == pytest.approx(0.1)
    assert np.all(ekf.x[6:] == 0.0)
    assert ekf.P[6, 6] == pytest.approx(1e-4 * ((1 - 0.05**2 / 2) ** 2 + 0.05**2))
    ekf.x[6] = 20.0  # absurd: dropped
    ekf.finalize()
    assert quat_to_rpy(ekf.q)[2] == pytest.approx(0.1) and ekf.x[6] == 0.0


# ------------------------------------------------------------------------ measurements
def test_models_values() -> None:
    h, H = measurements.twr(np.array([1.0, 2.0, 2.0]), np.zeros(3))  # type: ignore[misc]
    assert h == pytest.approx(3.0) and H == pytest.approx([1 / 3, 2 / 3, 2 / 3])
    h, H = measurements.tdoa(np.zeros(3), np.array([3.0, 0.0, 4.0]), np.array([0.0, -1.0, 0.0]))  # type: ignore[misc]
    assert h == pytest.approx(-4.0) and H == pytest.approx([0.6, 1.0, 0.8])


@pytest.mark.parametrize("p", [[0.3, -1.2, 1.5], [2.5, 3.0, 0.2], [-3.0, 0.1, 2.9]])
def test_models_jacobians_vs_finite_differences(p: list[float]) -> None:
    p0 = np.array(p)
    eps = 1e-6
    for j in range(8):
        a, b = ANCHORS[j], ANCHORS[(j + 1) % 8]
        for model, args in ((measurements.twr, (a,)), (measurements.tdoa, (a, b))):
            res = model(p0, *args)  # type: ignore[operator]
            assert res is not None
            fd = [(model(p0 + eps * e, *args)[0] - model(p0 - eps * e, *args)[0]) / (2 * eps)  # type: ignore[operator]
                  for e in np.eye(3)]
            np.testing.assert_allclose(res[1], fd, atol=1e-7)


def test_models_degenerate() -> None:
    a, b = np.zeros(3), np.array([4.0, 0.0, 0.0])
    assert measurements.twr(a, a) is None
    assert measurements.twr(np.array([0.0, 0.0, 5e-7]), a) is None
    assert measurements.twr(np.array([0.0, 0.0, 2e-6]), a) is not None
    assert measurements.twr(np.array([np.nan, 0.0, 0.0]), a) is None
    assert measurements.tdoa(a, a, b) is None
    assert measurements.tdoa(b, a, b) is None
    assert measurements.tdoa(np.ones(3), a, a) is None


# ----------------------------------------------------------------------------------- gates
def test_gates_at_their_boundaries() -> None:
    assert gates.kinematic_dmax(np.array([3.0, 4.0, 0.0]), 0.1, 10.0) == pytest.approx(0.55)
    assert gates.kinematic_dt(None, 0.01) == 0.01
    assert gates.kinematic_dt(5000, 0.01) == 0.01
    assert gates.kinematic_dt(-5000, 0.01) == 0.01
    assert gates.kinematic_dt(20000, 0.01) == pytest.approx(0.02)
    assert gates.kinematic_pass(0.25, 0.25, 1.0) and gates.kinematic_pass(-0.25, 0.25, 1.0)
    assert not gates.kinematic_pass(np.nextafter(0.25, 1.0), 0.25, 1.0)
    assert gates.kinematic_pass(0.5, 0.25, 2.0) and not gates.kinematic_pass(np.nextafter(0.5, 1.0), 0.25, 2.0)
    assert not gates.kinematic_pass(float("nan"), 0.25, 1.0)
    assert gates.chi2_pass(2.0, 1.0, 4.0) and not gates.chi2_pass(2.0, 1.0, np.nextafter(4.0, 0.0))
    assert not gates.chi2_pass(float("nan"), 1.0, 4.0)


def test_kinematic_gate_window_state() -> None:
    """The same sequence as test_window_state in firmware_sim/tests/test_gates.c."""
    g = gates.KinematicGate()
    assert g.window(1000, (0, 0), None, 0.01) == 0.01                       # no reference time
    assert g.window(20000, (1, 1), 15000, 0.01) == 0.01                     # 5 ms, floored
    g.fused(20000, (1, 1))                                                   # every anchor's clock starts
    assert g.t_anchor_fused_us[7] == 20000
    assert g.window(1020000, (1, 1), 1015000, 0.01) == pytest.approx(1.0)   # from the last fusion
    g.fused(1020000, (2, 2))
    assert g.window(1030000, (2, 2), 1025000, 0.01) == 0.01
    assert g.window(1040000, (1, 1), 1035000, 0.01) == pytest.approx(1.02)  # + 1 s anchor 1 was rejected
    assert g.window(1050000, (2, 1), 1045000, 0.01) == pytest.approx(1.05)  # TDoA: the longer of the two
    g.fused(1050000, (2, 1))
    assert g.window(1060000, (1, 1), 1055000, 0.01) == 0.01                 # nominal again
    assert g.window(1070000, (200, 3), 1065000, 0.01) == pytest.approx(0.02)
    g.reset()
    assert g.t_fused_us is None and g.t_anchor_seen_us[1] == 0 and g.t_anchor_fused_us[1] == 0


# -------------------------------------------------------------------------------- features
def test_features_layouts() -> None:
    tag, rpy = np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.3])
    a, b = np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 4.0])
    assert features(LAYOUT_TWR_POSE, tag, rpy, a) == pytest.approx([-1, -2, -3, 0.1, 0.2, 0.3])
    assert features(LAYOUT_TWR_POS, tag, rpy, a) == pytest.approx([-1, -2, -3])
    assert features(LAYOUT_TDOA_POSE, tag, rpy, a, b) == pytest.approx([-1, -2, -3, 3, 2, 1, 0.1, 0.2, 0.3])
    assert features(LAYOUT_TDOA_POS, tag, rpy, a, b) == pytest.approx([-1, -2, -3, 3, 2, 1])
    assert features(99, tag, rpy, a).size == 0
    assert [layout_inputs(k) for k in range(6)] == [0, 6, 9, 3, 6, 0]


# ------------------------------------------------------------------------------- estimator
def run_static(twin: TwinEstimator, truth: np.ndarray, seconds: float) -> None:
    k = 0
    for t in range(0, int(seconds * 1e6) + 1, 1000):
        twin.on_imu(t, STILL, NO_GYRO)
        if t % 10000 == 5000:
            twin.on_twr(t, k, float(np.linalg.norm(truth - ANCHORS[k])))
            k = (k + 1) % 8


def test_radio_positions_expire_host_positions_stay() -> None:
    twin = TwinEstimator(config(), {0: ANCHORS[0]})
    twin.set_anchor(200, ANCHORS[1], radio_t_us=1_000_000)
    twin.set_anchor(0, ANCHORS[2], radio_t_us=1_000_000)         # the host's position stays
    assert np.array_equal(twin.anchors[0], ANCHORS[0])
    twin.on_tdoa(2_999_000, 0, 200, 0.1)
    with pytest.raises(TwinError) as e:
        twin.on_tdoa(3_000_000, 0, 200, 0.1)                 # 2 s after it was received
    assert e.value.code == ERR_UNKNOWN_ANCHOR


def test_refusals_leave_the_state_unchanged() -> None:
    twin = TwinEstimator(config(init_z=1.0), ANCHORS)
    full = TwinEstimator(config(), {240 + k: np.zeros(3) for k in range(16)})   # any 8-bit id, 16 slots
    with pytest.raises(TwinError) as e:
        full.set_anchor(16, np.zeros(3))
    assert e.value.code == ERR_BAD_ANCHOR_ID
    with pytest.raises(TwinError) as e:
        twin.on_twr(1000, 12, 3.0)
    assert e.value.code == ERR_UNKNOWN_ANCHOR
    twin.on_imu(2000, STILL, NO_GYRO)
    twin.on_twr(5000, 0, 4.0)
    before = twin.state()
    for call in (lambda: twin.on_imu(1999, STILL, NO_GYRO), lambda: twin.on_twr(4999, 0, 4.0),
                 lambda: twin.on_tdoa(4999, 0, 1, 0.1)):
        with pytest.raises(TwinError) as e:
            call()
        assert e.value.code == ERR_TIME_BACKWARDS
    after = twin.state()
    assert np.array_equal(before.pos, after.pos) and np.array_equal(before.var, after.var)
    twin.on_imu(3000, STILL, NO_GYRO)  # separate clocks
    twin.configure(twin.config, reset=True)
    twin.on_twr(0, 0, 4.0)  # a reset forgets the time references
    with pytest.raises(ConfigError):
        TwinEstimator(config(std_twr=0.0), ANCHORS)


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY])
def test_static_convergence(mode: int) -> None:
    truth = np.array([1.0, -0.5, 1.2])
    twin = TwinEstimator(config(mode=mode, stages=0), ANCHORS)
    run_static(twin, truth, 10.0)
    s = twin.state()
    assert s.pos == pytest.approx(truth, abs=0.005)
    assert np.all(np.abs(s.vel) < 0.01)
    if mode == MODE_UWB_ONLY:
        assert twin.imu_ignored == 10001 and np.array_equal(s.quat, [1.0, 0.0, 0.0, 0.0])
    else:
        assert twin.predictions == 1000


def test_uwb_only_tracks_constant_velocity() -> None:
    v, p0 = np.array([0.5, -0.3, 0.1]), np.array([-1.0, 1.0, 1.0])
    twin = TwinEstimator(config(mode=MODE_UWB_ONLY, init_x=-1.0, init_y=1.0, init_z=1.0), ANCHORS)
    for k in range(500):
        p = p0 + v * 0.01 * k
        a, b = k % 8, (k + 1) % 8
        r = twin.on_tdoa(k * 10000, a, b, float(np.linalg.norm(p - ANCHORS[b]) - np.linalg.norm(p - ANCHORS[a])))
        assert r.status == ACCEPTED
        if k > 300:
            assert r.pos == pytest.approx(p, abs=0.005)
    assert twin.state().vel == pytest.approx(v, abs=0.01)
    assert twin.predictions == 499


def test_statuses_and_reported_fields() -> None:
    p0 = np.array([0.0, 0.0, 1.0])
    anchors = {**ANCHORS, 9: p0}
    twin = TwinEstimator(config(init_z=1.0), anchors)
    r = twin.on_twr(1000, 9, 0.5)
    assert r.status == REJECTED_GEOMETRY and r.innovation == 0.0 and r.d_max == pytest.approx(0.25)
    h = float(np.linalg.norm(p0 - ANCHORS[0]))
    r = twin.on_twr(2000, 0, h + 0.3)
    assert r.status == REJECTED_KINEMATIC and r.innovation == pytest.approx(0.3) and not r.gain.any()
    assert r.pos == pytest.approx(p0)
    r = twin.on_twr(2000, 0, h + 0.2)
    assert r.status == ACCEPTED and r.gain.any()
    twin = TwinEstimator(config(init_z=1.0, stages=STAGE_CHI2_GATE), ANCHORS)
    r = twin.on_twr(1000, 0, h + 3.0)
    assert r.status == REJECTED_CHI2 and r.mahalanobis**2 > twin.config.chi2_twr and r.d_max == pytest.approx(0.25)
    twin = TwinEstimator(config(init_z=1.0, stages=STAGE_KINEMATIC_GATE), ANCHORS)
    r = twin.on_tdoa(1000, 0, 1, float(np.linalg.norm(p0 - ANCHORS[1]) - np.linalg.norm(p0 - ANCHORS[0])) + 0.45)
    assert r.status == ACCEPTED  # TDoA: 2 d_max = 0.5 m


@dataclass
class SumNet:
    """A fake network recording its inputs; bias = 0.01 * sum(features)."""

    layout: int
    seen: list[np.ndarray]

    def predict(self, f: np.ndarray) -> float:
        self.seen.append(f.copy())
        return 0.01 * float(np.sum(f))


@dataclass
class Model:
    twr: SumNet | None = None
    tdoa: SumNet | None = None


def test_bias_network_uses_the_estimate() -> None:
    p0 = np.array([0.5, -0.5, 1.0])
    net = SumNet(LAYOUT_TWR_POSE, [])
    twin = TwinEstimator(config(init_x=0.5, init_y=-0.5, init_z=1.0, stages=STAGE_BIAS_NN), ANCHORS, Model(twr=net))
    h = float(np.linalg.norm(p0 - ANCHORS[7]))
    r = twin.on_twr(1000, 7, h)
    assert net.seen[0] == pytest.approx(np.concatenate([ANCHORS[7] - p0, np.zeros(3)]))
    assert r.bias == pytest.approx(0.01 * np.sum(ANCHORS[7] - p0))
    assert r.innovation == pytest.approx(-r.bias)
    assert twin.on_tdoa(2000, 6, 7, 0.1).bias == 0.0  # no TDoA network
    p_low = np.array([0.0, 0.0, 0.4])
    low = TwinEstimator(config(init_z=0.4, stages=STAGE_BIAS_NN), ANCHORS, Model(twr=net))
    assert low.on_twr(1000, 7, 3.0).bias == pytest.approx(0.01 * np.sum(ANCHORS[7] - p_low))  # power-up: any height
    floor = TwinEstimator(config(init_z=0.4, nn_min_z=0.5, stages=STAGE_BIAS_NN), ANCHORS, Model(twr=net))
    assert floor.on_twr(1000, 7, 3.0).bias == 0.0  # below nn_min_z
    off = TwinEstimator(config(init_z=1.0, stages=0), ANCHORS, Model(twr=net))
    assert off.on_twr(1000, 7, 3.0).bias == 0.0


def test_divergence_guard() -> None:
    truth = np.array([0.5, 0.5, 1.0])
    twin = TwinEstimator(config(stages=0, init_x=0.5, init_y=0.5, init_z=1.0), ANCHORS)
    run_static(twin, truth, 1.0)
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(1_001_000, 1_011_000, 1000):
            twin.on_imu(t, np.array([1e308, 0.0, GRAVITY]), NO_GYRO)  # the sum overflows
        assert twin.divergences == 1
        s = twin.state()
        assert s.pos == pytest.approx(truth, abs=0.01) and s.var[0] == twin.config.init_std_xy**2
        assert twin.on_twr(1_010_000, 0, 1e300).status == ACCEPTED  # position thrown out of any network
    assert twin.divergences == 2 and twin.state().pos == pytest.approx(truth, abs=0.01)


def test_run_flight_feeds_every_event() -> None:
    truth = np.array([1.0, 0.5, 1.5])
    t_imu = np.arange(0, 1_000_001, 1000, dtype=np.int64)
    t_uwb = np.arange(5000, 1_000_000, 10000, dtype=np.int64)
    ids = np.arange(len(t_uwb)) % 8
    pos = np.array([ANCHORS[i] for i in range(8)])
    ranges = np.linalg.norm(truth - pos[ids], axis=1)
    flight = Flight(
        name="static", anchors=Anchors(ids=np.arange(8), positions=pos),
        uwb=UwbStream(kind=KIND_TWR, t_us=t_uwb, anchor_a=ids, anchor_b=-np.ones_like(ids), value=ranges),
        truth=Truth(t_us=t_uwb, pos=np.tile(truth, (len(t_uwb), 1))),
        imu=ImuStream(t_us=t_imu, acc=np.tile(STILL, (len(t_imu), 1)), gyro=np.zeros((len(t_imu), 3))))
    cfg = config(init_x=1.0, init_y=0.5, init_z=1.5)
    results = run_flight(flight, cfg)
    assert len(results) == len(t_uwb)
    assert all(r.status == ACCEPTED for r in results)
    assert results[-1].pos == pytest.approx(truth, abs=1e-6)
