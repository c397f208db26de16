"""Crazyflie 2.x rigid-body model for the closed loop: four rotors in X configuration with thrust limits and
first-order motor lag, the on-board body-rate loop, linear rotor drag, and a ground the vehicle rests on.

The device commands a collective thrust [N] and body rates [rad/s] (CONTROL). On a Crazyflie the rate loop
runs at 500 Hz on the gyro; here it is part of the vehicle:
    tau_des = J K_rate (w_cmd - w) + w x J w          (PD-free: the motor lag provides the damping)
    [f1..f4] = mix^-1 [T, tau_x, tau_y, tau_z]         (yaw torque dropped first when a motor saturates)
    f_i' = (clip(f_i, 0, f_max) - f_i) / tau_motor
    m a = R (sum f_i) e3 - m g e3 - R D R^T v (+ ground reaction),   J w' = tau - w x J w
Parameters from Foerster, "System identification of the Crazyflie 2.0 nano quadrocopter" (ETH, 2015):
inertia, arm length, torque/thrust ratio, ~0.15 N per motor; the drag coefficient is the rotor-induced
drag at hover speed from the same report. Units SI, world z up, quaternion (w, x, y, z) body -> world.

Plain Python floats on purpose: a step is ~40 scalar operations, and numpy's per-call overhead on 3-vectors
would cost several times more at 500 steps per simulated second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from harness.errors import UsageError

GRAVITY = 9.81


@dataclass(frozen=True)
class VehicleParams:
    mass: float = 0.032                        # kg: Crazyflie 2.1 (27 g) + Loco deck and battery margin
    inertia: tuple[float, float, float] = (1.395e-5, 1.436e-5, 2.173e-5)   # kg m^2
    arm: float = 0.046                         # m, centre to motor
    f_max: float = 0.15                        # N per motor
    torque_ratio: float = 0.005964             # m: yaw torque per newton of thrust
    tau_motor: float = 0.03                    # s, first-order motor lag
    k_rate: tuple[float, float, float] = (40.0, 40.0, 15.0)   # 1/s, body-rate loop
    drag: tuple[float, float, float] = (0.0063, 0.0063, 0.0070)  # N/(m/s), body frame
    ground_z: float = 0.05                     # m: height of the UWB tag when the vehicle stands on the floor

    def validate(self) -> None:
        if not (0.01 <= self.mass <= 0.1):
            raise UsageError(f"vehicle mass {self.mass} kg is outside 0.01..0.1")
        if 4 * self.f_max <= self.mass * GRAVITY:
            raise UsageError(f"4 x f_max = {4 * self.f_max:.3f} N cannot lift {self.mass} kg")
        for name in ("arm", "f_max", "torque_ratio", "tau_motor"):
            if not getattr(self, name) > 0:
                raise UsageError(f"vehicle {name} must be > 0")
        if min(self.inertia) <= 0 or min(self.k_rate) <= 0 or min(self.drag) < 0:
            raise UsageError("vehicle inertia and k_rate must be > 0, drag >= 0")


@dataclass
class VehicleState:
    pos: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    vel: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])     # world
    quat: list[float] = field(default_factory=lambda: [1.0, 0.0, 0.0, 0.0])
    omega: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])   # body
    motors: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # N
    on_ground: bool = True


def quat_rot(q: list[float]) -> tuple[float, ...]:
    """Row-major body -> world rotation matrix of a unit quaternion."""
    w, x, y, z = q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def tilt_of(q: list[float]) -> float:
    """Angle between body z and world z [rad]."""
    w, x, y, z = q
    c = 1 - 2 * (x * x + y * y)
    return math.acos(max(-1.0, min(1.0, c)))


class Vehicle:
    """The simulated quadrotor. `step(thrust, rates, dt)` advances it; `specific_force` and `gyro` are what
    an ideal IMU measures after the step."""

    def __init__(self, params: VehicleParams = VehicleParams(), pos: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 yaw: float = 0.0) -> None:
        params.validate()
        self.p = params
        self.s = VehicleState(pos=[pos[0], pos[1], max(pos[2], params.ground_z)],
                              quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
        self.s.on_ground = self.s.pos[2] <= params.ground_z + 1e-9
        d = params.arm / math.sqrt(2.0)
        # Motors at (+d,-d), (-d,-d), (-d,+d), (+d,+d); diagonal pairs spin the same way.
        xs, ys, spin = (d, -d, -d, d), (-d, -d, d, d), (-1.0, 1.0, -1.0, 1.0)
        # Rows: T = sum f; tau_x = sum y_i f_i; tau_y = -sum x_i f_i; tau_z = k sum s_i f_i. Its inverse in
        # closed form (the X layout is symmetric): f_i = T/4 + tau_x/(4 y_i) - tau_y/(4 x_i) + tau_z/(4 k s_i).
        self._mix = [(0.25, 0.25 / ys[i], -0.25 / xs[i], 0.25 / (params.torque_ratio * spin[i])) for i in range(4)]
        self._geom = (xs, ys, spin)
        self.specific_force = (0.0, 0.0, GRAVITY)
        self.gyro = (0.0, 0.0, 0.0)

    @property
    def state(self) -> VehicleState:
        return self.s

    def _motor_targets(self, thrust: float, tau: tuple[float, float, float]) -> list[float]:
        fmax = self.p.f_max
        for yaw_scale in (1.0, 0.0):
            f = [m[0] * thrust + m[1] * tau[0] + m[2] * tau[1] + m[3] * tau[2] * yaw_scale for m in self._mix]
            if min(f) >= 0.0 and max(f) <= fmax:
                return f
        return [min(fmax, max(0.0, v)) for v in f]

    def _spin_motors(self, thrust_cmd: float, rate_cmd: tuple[float, float, float], dt: float) -> list[float]:
        """The body-rate loop's torques (with gyroscopic compensation) mixed to motor forces, each motor
        following its target with a first-order lag; the new motor forces (also stored in the state)."""
        p, s = self.p, self.s
        jx, jy, jz = p.inertia
        wx, wy, wz = s.omega
        tx = jx * p.k_rate[0] * (rate_cmd[0] - wx) + (jz - jy) * wy * wz
        ty = jy * p.k_rate[1] * (rate_cmd[1] - wy) + (jx - jz) * wz * wx
        tz = jz * p.k_rate[2] * (rate_cmd[2] - wz) + (jy - jx) * wx * wy
        target = self._motor_targets(max(0.0, thrust_cmd), (tx, ty, tz))
        a_m = min(1.0, dt / p.tau_motor)
        s.motors = [fi + (ti - fi) * a_m for fi, ti in zip(s.motors, target)]
        return s.motors

    def step(self, thrust_cmd: float, rate_cmd: tuple[float, float, float], dt: float) -> None:
        p, s = self.p, self.s
        jx, jy, jz = p.inertia
        wx, wy, wz = s.omega
        f = self._spin_motors(thrust_cmd, rate_cmd, dt)
        xs, ys, spin = self._geom
        thrust = f[0] + f[1] + f[2] + f[3]
        tau_x = sum(ys[i] * f[i] for i in range(4))
        tau_y = -sum(xs[i] * f[i] for i in range(4))
        tau_z = p.torque_ratio * sum(spin[i] * f[i] for i in range(4))

        r = quat_rot(s.quat)
        vx, vy, vz = s.vel
        # drag in the body frame: D R^T v
        vbx = r[0] * vx + r[3] * vy + r[6] * vz
        vby = r[1] * vx + r[4] * vy + r[7] * vz
        vbz = r[2] * vx + r[5] * vy + r[8] * vz
        fbx, fby, fbz = -p.drag[0] * vbx, -p.drag[1] * vby, thrust - p.drag[2] * vbz   # body force
        fwx = r[0] * fbx + r[1] * fby + r[2] * fbz
        fwy = r[3] * fbx + r[4] * fby + r[5] * fbz
        fwz = r[6] * fbx + r[7] * fby + r[8] * fbz
        m = p.mass
        ax, ay, az = fwx / m, fwy / m, fwz / m - GRAVITY

        if s.on_ground and az <= 0.0:
            # Standing on the floor: the ground holds it (and friction holds it in place, attitude level).
            s.vel = [0.0, 0.0, 0.0]
            s.omega = [0.0, 0.0, 0.0]
            s.pos[2] = p.ground_z
            self.specific_force = (0.0, 0.0, GRAVITY)   # level on the floor: only the reaction force
            self.gyro = (0.0, 0.0, 0.0)
            return
        s.on_ground = False

        # rotation: J w' = tau - w x J w
        dwx = (tau_x - (jz - jy) * wy * wz) / jx
        dwy = (tau_y - (jx - jz) * wz * wx) / jy
        dwz = (tau_z - (jy - jx) * wx * wy) / jz
        wx, wy, wz = wx + dwx * dt, wy + dwy * dt, wz + dwz * dt
        s.omega = [wx, wy, wz]
        s.quat = _rotate_quat(s.quat, (wx, wy, wz), dt)
        # translation, semi-implicit Euler
        vx, vy, vz = vx + ax * dt, vy + ay * dt, vz + az * dt
        px, py, pz = s.pos[0] + vx * dt, s.pos[1] + vy * dt, s.pos[2] + vz * dt
        specific = (fbx / m, fby / m, fbz / m)
        if pz <= p.ground_z:
            # Touch-down: the floor stops it. (A hard impact is judged by the mission, not modelled.)
            pz = p.ground_z
            vx = vy = vz = 0.0
            s.on_ground = True
            s.quat = [math.cos(self.yaw() / 2), 0.0, 0.0, math.sin(self.yaw() / 2)]
            s.omega = [0.0, 0.0, 0.0]
            specific = (0.0, 0.0, GRAVITY)
        s.vel = [vx, vy, vz]
        s.pos = [px, py, pz]
        self.specific_force = specific
        self.gyro = (s.omega[0], s.omega[1], s.omega[2])

    def yaw(self) -> float:
        w, x, y, z = self.s.quat
        return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))

    def tilt(self) -> float:
        return tilt_of(self.s.quat)


def _rotate_quat(quat: list[float], omega: tuple[float, float, float], dt: float) -> list[float]:
    """q <- q (x) exp(w dt / 2), exact for a constant body rate over the step, renormalised."""
    wx, wy, wz = omega
    ang = math.sqrt(wx * wx + wy * wy + wz * wz) * dt
    if ang > 1e-12:
        k = math.sin(ang / 2) / (ang / dt)
        dq = (math.cos(ang / 2), wx * k, wy * k, wz * k)
    else:
        dq = (1.0, wx * dt / 2, wy * dt / 2, wz * dt / 2)
    qw, qx, qy, qz = quat
    nq = [qw * dq[0] - qx * dq[1] - qy * dq[2] - qz * dq[3],
          qw * dq[1] + qx * dq[0] + qy * dq[3] - qz * dq[2],
          qw * dq[2] - qx * dq[3] + qy * dq[0] + qz * dq[1],
          qw * dq[3] + qx * dq[2] - qy * dq[1] + qz * dq[0]]
    n = math.sqrt(nq[0] ** 2 + nq[1] ** 2 + nq[2] ** 2 + nq[3] ** 2)
    return [c / n for c in nq]
