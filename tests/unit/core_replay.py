"""What the core-vs-twin tests share (test_core_vs_twin*.py, test_takeoff.py): a synthetic flight with exact
geometry and IMU readings, firmware_sim/tools/replay_core built with the firmware's flags (the `replay_core`
fixture), the event stream it reads, its results, and the core = twin comparison."""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from harness.config import STAGES_OUTLIER, EstimatorConfig
from harness.flight.data import KIND_TWR, Anchors, Flight, ImuStream, Source, Truth, UwbStream
from harness.twin.estimator import TwinResult

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
