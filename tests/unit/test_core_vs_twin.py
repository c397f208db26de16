"""The C estimator core against the numpy twin, without the wire protocol.

firmware_sim/tools/replay_core.c is compiled with the firmware's flags and fed a text event stream;
the twin gets the same (float32-rounded) flight. Statuses must match exactly and positions to
1e-4 m, in IMU and UWB-only mode, noiseless and with noise plus outliers (so the gates fire).
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import (MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, STAGE_CHI2_GATE, STAGE_KINEMATIC_GATE, STAGES_OUTLIER,
                            EstimatorConfig)
from harness.flight.data import (KIND_TDOA, KIND_TWR, Anchors, Flight, HeightStream, ImuStream, Source, Truth,
                                 UwbStream)
from harness.twin.estimator import (ACCEPTED, FLAG_COVARIANCE, FLAG_DIVERGED, FLAG_GAP_RESTART, FLAG_HEIGHT_FUSED,
                                    FLAG_OUT_OF_BOX, FLAG_SPEED, REJECTED_CHI2, REJECTED_KINEMATIC, TwinEstimator,
                                    TwinResult, run_flight)

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_sim"
GRAVITY = 9.81


# --------------------------------------------------------------------------------- the flight
def box_anchors() -> np.ndarray:
    """(8, 3): vertices of a 7 x 8 x 3 m box centred at the origin, z from 0 to 3."""
    return np.array([[x, y, z] for z in (0.0, 3.0) for y in (-4.0, 4.0) for x in (-3.5, 3.5)])


def trajectory(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact kinematics at times ``t`` (N,) [s]: position, velocity, acceleration (N, 3) and
    ZYX Euler angles with their rates (N, 3).

    1 s at rest at (1, 0, 1.5), a 2 s smooth ramp-up, then a 1 m circle at 1.5 m height with a
    6 s period (1.05 m/s, 1.1 m/s^2); small roll/pitch oscillations and a yaw that turns.
    """
    w, r, t0, ramp = 2 * np.pi / 6, 1.0, 1.0, 2.0
    tt = np.clip(t - t0, 0.0, None)
    u = np.clip(tt / ramp, 0.0, 1.0)
    th = np.where(tt < ramp, w * ramp * (u**3 - u**4 / 2), w * ramp / 2 + w * (tt - ramp))
    thd = np.where(tt < ramp, w * (3 * u**2 - 2 * u**3), w)
    thdd = np.where(tt < ramp, w * (6 * u - 6 * u**2) / ramp, 0.0)
    c, s = np.cos(th), np.sin(th)
    pos = np.stack([r * c, r * s, np.full_like(t, 1.5)], axis=1)
    vel = np.stack([-r * s * thd, r * c * thd, np.zeros_like(t)], axis=1)
    acc = np.stack([-r * c * thd**2 - r * s * thdd, -r * s * thd**2 + r * c * thdd, np.zeros_like(t)], axis=1)
    rpy = np.stack([0.08 * np.sin(1.3 * t), 0.06 * np.sin(0.9 * t), 0.5 * th], axis=1)
    rpy_dot = np.stack([0.08 * 1.3 * np.cos(1.3 * t), 0.06 * 0.9 * np.cos(0.9 * t), 0.5 * thd], axis=1)
    return pos, vel, acc, rpy, rpy_dot


def rot_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body -> world rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (3, 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def imu_readings(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Specific force ``R^T (a + g e3)`` and body rates (ZYX Euler-rate kinematics), each (N, 3)."""
    _, _, acc, rpy, rd = trajectory(t)
    f = np.empty_like(acc)
    for k in range(len(t)):
        f[k] = rot_zyx(*rpy[k]).T @ (acc[k] + np.array([0.0, 0.0, GRAVITY]))
    roll, pitch = rpy[:, 0], rpy[:, 1]
    gyro = np.stack([rd[:, 0] - rd[:, 2] * np.sin(pitch),
                     rd[:, 1] * np.cos(roll) + rd[:, 2] * np.sin(roll) * np.cos(pitch),
                     -rd[:, 1] * np.sin(roll) + rd[:, 2] * np.cos(roll) * np.cos(pitch)], axis=1)
    return f, gyro


def f32(x: np.ndarray) -> np.ndarray:
    """Round to float32 (what the device receives) and back to float64."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def synthetic_flight(kind: int, noise: float = 0.0, outliers: bool = False, duration_s: float = 8.0,
                     seed: int = 1) -> Flight:
    """IMU at 1 kHz, TWR round robin or TDoA between consecutive anchors at 200 Hz."""
    rng = np.random.default_rng(seed)
    anchors = f32(box_anchors())
    t_imu = np.arange(0, int(duration_s * 1e6) + 1, 1000, dtype=np.int64)
    acc, gyro = imu_readings(t_imu * 1e-6)
    t_uwb = np.arange(2500, int(duration_s * 1e6), 5000, dtype=np.int64)
    truth_pos, truth_vel, _, _, _ = trajectory(t_uwb * 1e-6)
    k = np.arange(len(t_uwb))
    a, b = k % 8, (k + 1) % 8
    if kind == KIND_TWR:
        true_value = np.linalg.norm(truth_pos - anchors[a], axis=1)
        b = np.full_like(a, -1)
    else:
        true_value = np.linalg.norm(truth_pos - anchors[b], axis=1) - np.linalg.norm(truth_pos - anchors[a], axis=1)
    value = true_value + noise * rng.standard_normal(len(k))
    if outliers:
        value[37::97] += 1.0   # far beyond d_max: kinematic gate
        value[61::97] -= 0.4   # between the chi-square bound and d_max (chi-square-only runs)
    uwb = UwbStream(kind=kind, t_us=t_uwb, anchor_a=a, anchor_b=b, value=f32(value), true_value=true_value)
    flight = Flight(name=f"synthetic-{kind}", anchors=Anchors(ids=np.arange(8), positions=anchors), uwb=uwb,
                    truth=Truth(t_us=t_uwb, pos=truth_pos, vel=truth_vel),
                    imu=ImuStream(t_us=t_imu, acc=f32(acc), gyro=f32(gyro)))
    flight.validate()
    return flight


# ------------------------------------------------------------------------------ the C side
@pytest.fixture(scope="session")
def replay_core(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """firmware_sim/tools/replay_core built with the firmware's warning flags."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    if not (FW / "core" / "bias_nn.c").exists():
        pytest.skip("firmware_sim/core/bias_nn.c is not there yet")
    exe = tmp_path_factory.mktemp("replay") / "replay_core"
    sources = sorted(str(p) for p in (FW / "core").glob("*.c"))
    cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wpointer-arith", "-Wstrict-prototypes",
           "-Wmissing-prototypes", "-Icore", "-Iproto", "-Iapp", "-Imodels", "-O2", "-D_POSIX_C_SOURCE=200809L",
           "-o", str(exe), *sources, "host/platform_host.c", "tools/replay_core.c", "-lm"]
    subprocess.run(cmd, cwd=FW, check=True, capture_output=True, text=True)
    return exe


def event_stream(flight: Flight, cfg: EstimatorConfig) -> str:
    """The replay_core text stream of ``flight`` under ``cfg``."""
    lines = ["C " + " ".join(f"{name}={value!r}" for name, value in asdict(cfg).items())]
    for i, p in zip(flight.anchors.ids, flight.anchors.positions):
        lines.append(f"A {int(i)} " + " ".join(repr(float(v)) for v in p))
    u, imu, hgt = flight.uwb, flight.imu, flight.height
    for t, source, i in flight.events():
        if source == Source.IMU:
            assert imu is not None
            lines.append(f"I {t} " + " ".join(repr(float(v)) for v in (*imu.acc[i], *imu.gyro[i])))
        elif source == Source.HEIGHT:
            assert hgt is not None
            lines.append(f"H {t} {float(hgt.z[i])!r} {float(hgt.std)!r}")
        elif u.kind == KIND_TWR:
            lines.append(f"T {t} {int(u.anchor_a[i])} {float(u.value[i])!r}")
        else:
            lines.append(f"D {t} {int(u.anchor_a[i])} {int(u.anchor_b[i])} {float(u.value[i])!r}")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class CRun:
    status: np.ndarray      # (M,)
    innovation: np.ndarray  # (M,)
    S: np.ndarray           # (M,)
    pos: np.ndarray         # (M, 3)
    var: np.ndarray         # (M, 9)
    flags: np.ndarray       # (M,) supervisor events since the previous result
    predictions: int
    divergences: int
    heights: int


def run_c(exe: Path, flight: Flight, cfg: EstimatorConfig, with_model: bool = False) -> CRun:
    """``with_model``: the compiled-in bias networks run (else --no-model)."""
    args = [str(exe)] if with_model else [str(exe), "--no-model"]
    out = subprocess.run(args, input=event_stream(flight, cfg), capture_output=True,
                         text=True, check=True).stdout.splitlines()
    assert not [line for line in out if line.startswith("E")], "the core refused an input"
    rows = np.array([[float(v) for v in line.split()[1:]] for line in out if line.startswith("R")])
    summary = out[-1].split()
    return CRun(status=rows[:, 0].astype(int), innovation=rows[:, 1], S=rows[:, 2], pos=rows[:, 8:11],
                var=rows[:, 18:27], flags=rows[:, 27].astype(int), predictions=int(summary[1]),
                divergences=int(summary[2]), heights=int(summary[3]))


def assert_core_equals_twin(c: CRun, twin: list[TwinResult], innovation_var: bool = False) -> None:
    """Same statuses as the twin, positions within float32 noise (and S within 0.1 % when asked)."""
    np.testing.assert_array_equal(c.status, np.array([r.status for r in twin]))
    assert np.max(np.abs(c.pos - np.array([r.pos for r in twin]))) < 1e-4
    if innovation_var:
        t_s = np.array([r.innovation_var for r in twin])
        assert np.max(np.abs(c.S - t_s) / t_s) < 1e-3


def rmse(pos: np.ndarray, flight: Flight) -> float:
    return float(np.sqrt(np.mean(np.sum((pos - flight.truth.pos) ** 2, axis=1))))


def base_config(flight: Flight, mode: int, stages: int = STAGES_OUTLIER) -> EstimatorConfig:
    p0 = flight.truth.pos[0]
    return replace(EstimatorConfig(), mode=mode, stages=stages).with_init(*p0)


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
