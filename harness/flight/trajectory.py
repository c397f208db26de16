"""Quadrotor trajectories: smooth paths, speed envelopes, take-off/landing, and the attitude a quadrotor
must have to fly them (differential flatness: thrust along commanded acceleration + gravity, plus yaw).

A trajectory is a vectorised function t -> (position, yaw). Velocity, acceleration and body rates are
taken by central differences of those analytic functions (h = 1 ms evaluated at arbitrary t, not of
sampled data), which is accurate to ~1e-7 relative for these smooth paths and keeps every trajectory a
few lines long. Specific force is then exactly R^T (a + g e_z), so the IMU integrates back to the path.

Conventions (docs/ARCHITECTURE.md): world z up, quaternion (w, x, y, z) body -> world.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

GRAVITY = 9.81          # same constant as the firmware and the twin
_H = 1e-3               # finite-difference step [s]

PosFn = Callable[[np.ndarray], np.ndarray]   # (N,) s -> (N, 3) m
YawFn = Callable[[np.ndarray], np.ndarray]   # (N,) s -> (N,) rad (continuous, unwrapped)


# ------------------------------------------------------------------------------- smooth primitives
def smoothstep7(u: np.ndarray) -> np.ndarray:
    """0 -> 1 on [0, 1] with zero 1st, 2nd and 3rd derivatives at both ends (so jerk, hence body rate,
    stays continuous when segments are joined)."""
    u = np.clip(u, 0.0, 1.0)
    return u ** 4 * (35.0 - 84.0 * u + 70.0 * u ** 2 - 20.0 * u ** 3)


def _smoothstep7_integral(u: np.ndarray) -> np.ndarray:
    """Integral of smoothstep7 from 0 to u (u in [0, 1]); equals 0.5 at u = 1."""
    u = np.clip(u, 0.0, 1.0)
    return u ** 5 * (7.0 - 14.0 * u + 10.0 * u ** 2 - 2.5 * u ** 3)


def envelope_time(t: np.ndarray, duration: float, ramp: float) -> np.ndarray:
    """Warped time tau(t) = integral of a speed envelope that rises 0 -> 1 over `ramp` seconds, stays at 1
    and falls back to 0 over the last `ramp` seconds of `duration`. A path q(tau(t)) starts and ends at
    rest with zero acceleration and jerk, whatever q is."""
    t = np.asarray(t, dtype=np.float64)
    ramp = min(ramp, duration / 2.0)
    if ramp <= 0.0:
        return np.clip(t, 0.0, duration)
    up = ramp * _smoothstep7_integral(t / ramp)
    flat = np.clip(t - ramp, 0.0, max(duration - 2.0 * ramp, 0.0))
    down_u = np.clip((t - (duration - ramp)) / ramp, 0.0, 1.0)
    # integral of (1 - s(u)) over the last ramp = u - S(u)
    down = ramp * (down_u - _smoothstep7_integral(down_u))
    return up + flat + down


# ------------------------------------------------------------------------------------- trajectory
@dataclass(frozen=True)
class Trajectory:
    """A flyable path: position and yaw as functions of time on [0, duration]."""

    name: str
    duration: float
    pos_fn: PosFn
    yaw_fn: YawFn

    def pos(self, t: np.ndarray) -> np.ndarray:
        return self.pos_fn(np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration))

    def yaw(self, t: np.ndarray) -> np.ndarray:
        return self.yaw_fn(np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration))


@dataclass(frozen=True)
class TrajectorySample:
    t: np.ndarray        # (N,) s
    pos: np.ndarray      # (N, 3) world
    vel: np.ndarray      # (N, 3) world
    acc: np.ndarray      # (N, 3) world (kinematic acceleration)
    quat: np.ndarray     # (N, 4) (w, x, y, z) body -> world
    omega: np.ndarray    # (N, 3) body angular rate [rad/s]
    f_body: np.ndarray   # (N, 3) specific force in the body frame [m/s^2]


def _rotation(acc: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body->world rotation (N, 3, 3) of a quadrotor producing `acc` with heading `yaw`."""
    thrust = acc + np.array([0.0, 0.0, GRAVITY])
    zb = thrust / np.linalg.norm(thrust, axis=1, keepdims=True)
    xc = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=1)
    yb = np.cross(zb, xc)
    yb /= np.linalg.norm(yb, axis=1, keepdims=True)
    xb = np.cross(yb, zb)
    return np.stack([xb, yb, zb], axis=2)


def rot_to_quat(r: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions (w, x, y, z), w >= 0 not enforced."""
    n = r.shape[0]
    q = np.empty((n, 4))
    tr = r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]
    # Shepperd: pick the largest of w, x, y, z to divide by, for accuracy everywhere.
    cand = np.stack([tr, r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]], axis=1)
    k = np.argmax(cand, axis=1)
    for case in range(4):
        m = k == case
        if not np.any(m):
            continue
        rr = r[m]
        if case == 0:
            s = 2.0 * np.sqrt(1.0 + tr[m])
            q[m] = np.stack([0.25 * s, (rr[:, 2, 1] - rr[:, 1, 2]) / s, (rr[:, 0, 2] - rr[:, 2, 0]) / s,
                             (rr[:, 1, 0] - rr[:, 0, 1]) / s], axis=1)
        elif case == 1:
            s = 2.0 * np.sqrt(1.0 + rr[:, 0, 0] - rr[:, 1, 1] - rr[:, 2, 2])
            q[m] = np.stack([(rr[:, 2, 1] - rr[:, 1, 2]) / s, 0.25 * s, (rr[:, 0, 1] + rr[:, 1, 0]) / s,
                             (rr[:, 0, 2] + rr[:, 2, 0]) / s], axis=1)
        elif case == 2:
            s = 2.0 * np.sqrt(1.0 + rr[:, 1, 1] - rr[:, 0, 0] - rr[:, 2, 2])
            q[m] = np.stack([(rr[:, 0, 2] - rr[:, 2, 0]) / s, (rr[:, 0, 1] + rr[:, 1, 0]) / s, 0.25 * s,
                             (rr[:, 1, 2] + rr[:, 2, 1]) / s], axis=1)
        else:
            s = 2.0 * np.sqrt(1.0 + rr[:, 2, 2] - rr[:, 0, 0] - rr[:, 1, 1])
            q[m] = np.stack([(rr[:, 1, 0] - rr[:, 0, 1]) / s, (rr[:, 0, 2] + rr[:, 2, 0]) / s,
                             (rr[:, 1, 2] + rr[:, 2, 1]) / s, 0.25 * s], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """(N, 4) (w, x, y, z) -> (N, 3, 3) body->world."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def quat_to_euler(q: np.ndarray) -> np.ndarray:
    """(N, 4) -> (N, 3) roll, pitch, yaw [rad], the firmware's formulas (docs/ARCHITECTURE.md)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=1)


#: where the previous slice of a chunked sampling ended: (its last raw quaternion, that sample's sign flip)
SampleCarry = tuple[np.ndarray, int]


def sample(traj: Trajectory, t: np.ndarray) -> TrajectorySample:
    """Position, velocity, acceleration, attitude, body rates and specific force at times t [s]."""
    return sample_continued(traj, t, None)[0]


def sample_continued(traj: Trajectory, t: np.ndarray, carry: SampleCarry | None,
                     carry_at: int = -1) -> tuple[TrajectorySample, SampleCarry]:
    """`sample` of one time slice of a longer sampling: `carry` (from the previous slice, None for the
    first) keeps the quaternion sign continuous across slices, so slices equal the whole sampling.
    Returns the carry of sample `carry_at` of this slice (the last one the next slice follows)."""
    t = np.asarray(t, dtype=np.float64)
    p = [traj.pos(t + k * _H) for k in (-2, -1, 0, 1, 2)]   # 5 evaluations give a(t-H), a(t), a(t+H)
    h2 = _H * _H
    acc_m, acc, acc_p = ((p[k - 1] - 2.0 * p[k] + p[k + 1]) / h2 for k in (1, 2, 3))
    pos = p[2]
    vel = (p[3] - p[1]) / (2.0 * _H)
    r0 = _rotation(acc, traj.yaw(t))
    rp = _rotation(acc_p, traj.yaw(t + _H))
    rm = _rotation(acc_m, traj.yaw(t - _H))
    rdot = (rp - rm) / (2.0 * _H)
    w_hat = np.einsum("nji,njk->nik", r0, rdot)      # R^T Rdot = [omega]x
    omega = np.stack([w_hat[:, 2, 1] - w_hat[:, 1, 2], w_hat[:, 0, 2] - w_hat[:, 2, 0],
                      w_hat[:, 1, 0] - w_hat[:, 0, 1]], axis=1) * 0.5
    thrust = acc + np.array([0.0, 0.0, GRAVITY])
    f_body = np.einsum("nji,nj->ni", r0, thrust)
    quat = rot_to_quat(r0)
    # keep the quaternion sign continuous (q and -q are the same attitude; interpolation needs continuity)
    if carry is None:
        first, parity = 0, 0
    else:
        first, parity = int(np.sum(quat[0] * carry[0]) < 0), carry[1]
    flip = (parity + np.cumsum(np.concatenate([[first], (np.sum(quat[1:] * quat[:-1], axis=1) < 0).astype(int)]))) % 2
    out_carry: SampleCarry = (quat[carry_at].copy(), int(flip[carry_at])) if len(quat) else (np.zeros(4), 0)
    quat[flip == 1] *= -1.0
    return TrajectorySample(t=t, pos=pos, vel=vel, acc=acc, quat=quat, omega=omega, f_body=f_body), out_carry


# ------------------------------------------------------------------------------------ path builders
def circle_path(center: np.ndarray, radius: float, speed: float, z_amp: float = 0.0, z_cycles: float = 1.0,
                phase0: float = 0.0) -> Callable[[np.ndarray], np.ndarray]:
    """Path q(tau) of a circle flown at `speed` (m/s on the horizontal circle when tau == t); optionally
    z = cz + z_amp sin(z_cycles * theta) (the paper's circle with varying height)."""
    omega = speed / radius
    c = np.asarray(center, dtype=np.float64)

    def q(tau: np.ndarray) -> np.ndarray:
        th = phase0 + omega * tau
        return np.stack([c[0] + radius * np.cos(th), c[1] + radius * np.sin(th),
                         c[2] + z_amp * np.sin(z_cycles * omega * tau)], axis=1)
    return q


def random_path(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n_terms: int = 4,
                f_min: float = 0.015, f_max: float = 0.12) -> Callable[[np.ndarray], np.ndarray]:
    """Smooth random 3-D path: per axis a sum of sinusoids with random frequencies/phases, scaled so the
    path always stays inside the box [lo, hi] (amplitudes sum to the half-width)."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    mid = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    freqs = rng.uniform(f_min, f_max, size=(3, n_terms))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(3, n_terms))
    w = rng.uniform(0.3, 1.0, size=(3, n_terms))
    amps = half[:, None] * w / w.sum(axis=1, keepdims=True)

    def q(tau: np.ndarray) -> np.ndarray:
        arg = 2.0 * np.pi * freqs[None, :, :] * tau[:, None, None] + phases[None, :, :]
        return mid[None, :] + np.sum(amps[None, :, :] * np.sin(arg), axis=2)
    return q


def compose_flight(name: str, path: Callable[[np.ndarray], np.ndarray], yaw_path: Callable[[np.ndarray], np.ndarray],
                   main_s: float, ramp_s: float, ground_z: float | None, takeoff_s: float = 4.0,
                   ground_wait_s: float = 1.0) -> Trajectory:
    """Fly `path` for `main_s` seconds with a speed envelope (start and end at rest). With `ground_z` set,
    the flight is: wait on the ground, take off vertically to the path's start, fly, land vertically.
    Yaw follows the same warped time, so spins ramp up and down smoothly too."""
    def warped(t: np.ndarray) -> np.ndarray:
        return envelope_time(t, main_s, ramp_s)

    if ground_z is None:
        return Trajectory(name, main_s, lambda t: path(warped(t)), lambda t: yaw_path(warped(t)))

    start = path(np.zeros(1))[0]
    tau_end = float(warped(np.array([main_s]))[0])
    end = path(np.array([tau_end]))[0]
    yaw0 = float(yaw_path(np.zeros(1))[0])
    yaw1 = float(yaw_path(np.array([tau_end]))[0])
    t_main0 = ground_wait_s + takeoff_s
    t_main1 = t_main0 + main_s
    total = t_main1 + takeoff_s + ground_wait_s

    def pos(t: np.ndarray) -> np.ndarray:
        out = np.empty((t.shape[0], 3))
        up = t < t_main0
        fly = (t >= t_main0) & (t <= t_main1)
        down = t > t_main1
        if np.any(up):
            s = smoothstep7((t[up] - ground_wait_s) / takeoff_s)
            out[up] = np.array([start[0], start[1], ground_z])[None, :] + s[:, None] * np.array(
                [0.0, 0.0, start[2] - ground_z])[None, :]
        if np.any(fly):
            out[fly] = path(warped(t[fly] - t_main0))
        if np.any(down):
            s = smoothstep7((t[down] - t_main1) / takeoff_s)
            out[down] = end[None, :] + s[:, None] * np.array([0.0, 0.0, ground_z - end[2]])[None, :]
        return out

    def yaw(t: np.ndarray) -> np.ndarray:
        out = np.where(t < t_main0, yaw0, yaw1)
        fly = (t >= t_main0) & (t <= t_main1)
        if np.any(fly):
            out = out.astype(np.float64)
            out[fly] = yaw_path(warped(t[fly] - t_main0))
        return out

    return Trajectory(name, total, pos, yaw)
