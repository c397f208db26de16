"""The C estimator core against the numpy twin with a bias network compiled in: a network with a std head under
each network preset, the correction fading outside the training range, the per-pair monitor switching a harmful
correction off, and the bias states following slow anchor biases (core_replay.py builds and runs the core)."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from core_replay import (FW, assert_core_equals_twin, base_config, f32, replay_core, rmse, run_c,  # noqa: F401
                         synthetic_flight)
from harness.config import MODE_IMU, MODE_UWB_ONLY, STAGES_OUTLIER
from harness.flight.data import KIND_TDOA, KIND_TWR, Flight
from harness.twin.estimator import REJECTED_CHI2, run_flight


# ----------------------------------------------------------- with a bias network that predicts its std
def std_head_model() -> "BiasModel":
    """Random pose networks (bias within +-0.1 m) with a std head spanning its bounds on this flight."""
    from harness.biasnet.network import BiasModel, init_network
    from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE
    rng = np.random.default_rng(21)
    lo6 = np.array([-6.0, -6.0, -3.0, -0.3, -0.3, -np.pi])
    lo9 = np.concatenate([lo6[:3], lo6])
    nets = {}
    for kind, layout, lo in (("twr", LAYOUT_TWR_POSE, lo6), ("tdoa", LAYOUT_TDOA_POSE, lo9)):
        net = init_network(layout, lo, -lo, -0.1, 0.1, rng)
        w3s = rng.normal(0.0, 6.0, 50).astype(np.float32)
        x = rng.uniform(net.in_min, net.in_max, size=(500, net.n_in))
        nets[kind] = replace(net, b3=net.b3 + 0.5, w3s=w3s, b3s=float(np.log(0.08) - np.mean(net.hidden(x) @ w3s)),
                             std_min=0.03, std_max=0.3)
    return BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name="std-head-test")


def narrowed(model: "BiasModel") -> "BiasModel":
    """The same networks trained (so to speak) on dp_x in [-3.6, 3.6] m only: the flight (|dp_x| from 2.5 to
    4.5 m) leaves that range part of the time."""
    from harness.biasnet.network import BiasModel
    nets = {}
    for kind in ("twr", "tdoa"):
        net = model.network(kind)
        assert net is not None
        lo, hi = net.in_min.copy(), net.in_max.copy()
        lo[0], hi[0] = -3.6, 3.6
        nets[kind] = replace(net, in_min=lo, in_max=hi)
    return BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name="narrow")


def build_replay_core(tmp_path_factory: pytest.TempPathFactory, model: "BiasModel") -> Path:
    from harness.biasnet.export import export_c
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    root = tmp_path_factory.mktemp("replay_model")
    header = export_c(model, root / "model.h")
    exe = root / "replay_core"
    sources = sorted(str(p) for p in (FW / "core").glob("*.c"))
    cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Icore", "-Iproto", "-Iapp", "-Imodels", "-O2",
           f"-DBIAS_MODEL_HEADER=\"{header}\"", "-D_POSIX_C_SOURCE=200809L", "-o", str(exe), *sources,
           "host/platform_host.c", "tools/replay_core.c", "-lm"]
    subprocess.run(cmd, cwd=FW, check=True, capture_output=True, text=True)
    return exe


@pytest.fixture(scope="module")
def replay_core_std(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, "BiasModel"]:
    model = std_head_model()
    return build_replay_core(tmp_path_factory, model), model


@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
@pytest.mark.parametrize("preset", ["outlier+nn", "outlier+nn+std", "robust+nn"])
def test_core_matches_twin_with_a_std_head_network(replay_core_std: tuple[Path, "BiasModel"], kind: int,
                                                   preset: str) -> None:
    from harness.config import PRESETS
    exe, model = replay_core_std
    flight = synthetic_flight(kind, noise=0.05, outliers=True, seed=11 + kind)
    cfg = base_config(flight, MODE_IMU, stages=PRESETS[preset])
    twin = run_flight(flight, cfg, model)
    c = run_c(exe, flight, cfg, with_model=True)
    assert_core_equals_twin(c, twin, innovation_var=True)
    t_s = np.array([r.innovation_var for r in twin])
    assert rmse(c.pos, flight) < 0.15
    std_cfg = cfg.std_tdoa if kind == KIND_TDOA else cfg.std_twr
    airborne = np.array([r.pos[2] for r in twin]) > cfg.nn_min_z
    if preset == "outlier+nn+std":
        # The network's std, not the configured one, is in S: S - H P H^T varies with the input, within
        # [std_min^2, std_max^2] (H P H^T >= 0, so S >= std_min^2 always, and often S < std_cfg^2).
        assert np.all(t_s[airborne] >= 0.03 ** 2 * 0.999)
        assert np.mean(t_s[airborne] < std_cfg ** 2) > 0.3
    else:  # the configured std: S >= std_cfg^2 always
        assert np.all(t_s >= std_cfg ** 2 * 0.999)
    if preset == "robust+nn":  # no chi-square gate: the -0.4 m outliers are accepted, down-weighted
        status = np.array([r.status for r in twin])
        assert not np.any(status == REJECTED_CHI2)
        if kind == KIND_TDOA:  # 0.4 m is 2.7 sigma at std_tdoa 0.15: R / w with w < 1 (1.6 sigma for TWR: ~1)
            assert np.all(t_s[61::97] > 1.2 * std_cfg ** 2)


@pytest.fixture(scope="module")
def replay_core_q15(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, "BiasModel"]:
    model = std_head_model().quantized("q15")
    return build_replay_core(tmp_path_factory, model), model


@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
def test_core_matches_twin_with_a_q15_network(replay_core_q15: tuple[Path, "BiasModel"], kind: int) -> None:
    """The q15 build (bias_nn_q15.c) and the twin's Q15Network compute the same integers from the same
    inputs. The inputs themselves differ by float32 noise (C's float32 state, the twin's float64): one that
    falls that close to a q15 rounding boundary moves by one step (2^-14 of its range). The positions stay
    within the usual 1e-4 m; S, through this test's steep std head (log-std weights ~N(0, 6)), within 1 %
    (0.4 % measured) where float32 vs float64 alone gives 0.1 %."""
    from harness.config import PRESETS
    exe, model = replay_core_q15
    flight = synthetic_flight(kind, noise=0.05, outliers=True, seed=11 + kind)
    cfg = base_config(flight, MODE_IMU, stages=PRESETS["outlier+nn+std"])
    twin = run_flight(flight, cfg, model)
    c = run_c(exe, flight, cfg, with_model=True)
    assert_core_equals_twin(c, twin)
    t_s = np.array([r.innovation_var for r in twin])
    assert np.max(np.abs(c.S - t_s) / t_s) < 1e-2 and np.median(np.abs(c.S - t_s) / t_s) < 1e-5
    bias = np.array([r.bias for r in twin])
    assert np.count_nonzero(bias) > 100       # the network ran
    assert rmse(c.pos, flight) < 0.15


@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
def test_correction_fades_outside_the_training_range_as_in_the_twin(tmp_path_factory: pytest.TempPathFactory,
                                                                     kind: int) -> None:
    from harness.config import PRESETS
    from harness.twin.features import OOD_MARGIN
    model = narrowed(std_head_model())
    exe = build_replay_core(tmp_path_factory, model)
    flight = synthetic_flight(kind, noise=0.05, outliers=True, seed=11 + kind)
    cfg = base_config(flight, MODE_IMU, stages=PRESETS["outlier+nn+std"])
    twin = run_flight(flight, cfg, model)
    c = run_c(exe, flight, cfg, with_model=True)
    assert_core_equals_twin(c, twin, innovation_var=True)
    t_s = np.array([r.innovation_var for r in twin])
    # Where the estimate's dp_x leaves [-3.6, 3.6] m by more than 10 % of the width the bias is exactly 0
    # and the std the configured one; inside it the network runs. Both happen on this flight.
    bias = np.array([r.bias for r in twin])
    airborne = np.array([r.pos[2] for r in twin]) > cfg.nn_min_z
    std_cfg = cfg.std_tdoa if kind == KIND_TDOA else cfg.std_twr
    zero = airborne & (bias == 0.0)
    assert 0.05 < np.mean(zero[airborne]) < 0.95
    assert np.all(t_s[zero] >= std_cfg ** 2 * 0.999)   # faded out: the configured std, not the head's
    assert OOD_MARGIN == pytest.approx(0.1)


def harmful_model() -> "BiasModel":
    """A network whose 'correction' is a wrong +0.25 to +0.35 m everywhere (out range [0.25, 0.35])."""
    from harness.biasnet.network import init_network
    from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE
    from harness.biasnet.network import BiasModel
    rng = np.random.default_rng(5)
    lo6 = np.array([-6.0, -6.0, -3.0, -0.3, -0.3, -np.pi])
    lo9 = np.concatenate([lo6[:3], lo6])
    return BiasModel(twr=init_network(LAYOUT_TWR_POSE, lo6, -lo6, 0.25, 0.35, rng),
                     tdoa=init_network(LAYOUT_TDOA_POSE, lo9, -lo9, 0.25, 0.35, rng), name="harmful")


@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
def test_pair_monitor_switches_a_harmful_correction_off_as_in_the_twin(tmp_path_factory: pytest.TempPathFactory,
                                                                        kind: int) -> None:
    from harness.config import PRESETS
    from harness.twin.estimator import FLAG_NN_PAIR_OFF
    model = harmful_model()
    exe = build_replay_core(tmp_path_factory, model)
    flight = synthetic_flight(kind, noise=0.05, seed=13 + kind)
    from harness.config import STAGE_NN_MONITOR
    # no chi-square gate hiding the damage
    cfg = base_config(flight, MODE_IMU, stages=PRESETS["robust+nn"] | STAGE_NN_MONITOR)
    twin = run_flight(flight, cfg, model)
    c = run_c(exe, flight, cfg, with_model=True)
    t_flags = np.array([r.flags for r in twin])
    np.testing.assert_array_equal(c.status, np.array([r.status for r in twin]))
    np.testing.assert_array_equal(c.flags, t_flags)
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-4
    off = np.flatnonzero(t_flags & FLAG_NN_PAIR_OFF)
    if kind == KIND_TDOA:
        # TDoA: the filter partly absorbs a common wrong offset into its position, which the innovations
        # then no longer show: only some pairs are caught (a limit of innovation monitoring)
        assert 1 <= len(off) <= 8
        return
    # TWR: every one of the flight's 8 anchors is switched off once, and the correction stops there
    assert len(off) == 8
    bias = np.array([r.bias for r in twin])
    assert np.all(bias[off[-1] + 1:] == 0.0) and np.any(bias[:off[0]] != 0.0)
    # after the last pair went off, the estimate recovers to what no correction gives
    plain = run_flight(flight, replace(cfg, stages=PRESETS["robust"]))
    assert not np.any(np.array([r.flags for r in run_flight(flight, replace(cfg, stages=PRESETS["robust+nn"]),
                                                            model)]) & FLAG_NN_PAIR_OFF)  # stage off: no monitor
    tail = slice(off[-1] + 400, None)
    err = np.linalg.norm(c.pos[tail] - flight.truth.pos[tail], axis=1)
    err_plain = np.linalg.norm(np.array([r.pos for r in plain])[tail] - flight.truth.pos[tail], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 1.5 * np.sqrt(np.mean(err_plain ** 2)) + 0.01


def with_anchor_biases(flight: Flight, amplitude: float, seed: int) -> Flight:
    """The flight with a slowly varying bias on each anchor's range (period 2-4 s, random phase): a TWR
    range gets beta_A(t), a TDoA d(B) - d(A) gets beta_B(t) - beta_A(t)."""
    rng = np.random.default_rng(seed)
    u = flight.uwb
    t = u.t_us * 1e-6
    period, phase = rng.uniform(2.0, 4.0, 8), rng.uniform(0.0, 2 * np.pi, 8)
    beta = amplitude * np.sin(2 * np.pi * t[:, None] / period + phase)  # (M, 8)
    rows = np.arange(len(t))
    add = beta[rows, u.anchor_a] * (1.0 if flight.uwb.kind == KIND_TWR else -1.0)
    if flight.uwb.kind == KIND_TDOA:
        add = add + beta[rows, u.anchor_b]
    return replace(flight, uwb=replace(u, value=f32(u.value + add)))


@pytest.mark.parametrize("mode", [MODE_IMU, MODE_UWB_ONLY], ids=["imu", "uwb_only"])
@pytest.mark.parametrize("kind", [KIND_TWR, KIND_TDOA], ids=["twr", "tdoa"])
def test_bias_states_match_twin_and_follow_slow_anchor_biases(replay_core: Path, mode: int, kind: int) -> None:
    from harness.config import STAGE_BIAS_STATES
    flight = with_anchor_biases(synthetic_flight(kind, noise=0.03, outliers=True, seed=17 + kind), 0.2, seed=kind)
    cfg = replace(base_config(flight, mode, stages=STAGES_OUTLIER | STAGE_BIAS_STATES), std_twr=0.1, std_tdoa=0.1)
    twin = run_flight(flight, cfg)
    c = run_c(replay_core, flight, cfg)
    np.testing.assert_array_equal(c.status, np.array([r.status for r in twin]))
    t_pos = np.array([r.pos for r in twin])
    assert np.max(np.abs(c.pos - t_pos)) < 1e-4
    t_s = np.array([r.innovation_var for r in twin])
    assert np.max(np.abs(c.S - t_s) / t_s) < 1e-3
    # the states subtract something once measured, and the filter tracks better (synthetic, 0.2 m biases:
    # TWR 0.22 against 0.32 m, TDoA 0.23 against 0.50 m in IMU mode; at 0.1 m and TWR the two are alike)
    assert np.mean(np.abs([r.bias for r in twin][100:])) > 0.01
    plain = np.array([r.pos for r in run_flight(flight, replace(cfg, stages=STAGES_OUTLIER))])
    assert rmse(t_pos, flight) < 0.85 * rmse(plain, flight)
