"""Lockstep co-simulation: the device's estimator and controller fly the simulated vehicle.

Every control step k (t_k = k * control_dt):
  1. integrate the vehicle from t_{k-1} to t_k under the previous CONTROL (physics_dt sub-steps, the
     vehicle's rate loop at each), producing an IMU sample per sub-step and the UWB measurements due,
     all from the TRUE state (measurements at their own times, position interpolated);
  2. send those frames in time order (IMU first at equal times), then SETPOINT(t_k);
  3. wait for the CONTROL answering that SETPOINT (RESULTs and ERRORs of the measurements come first:
     the device processes frames in order), and apply it from t_k on.
Lockstep makes a flight a pure function of (mission, configurations, seed): the same numbers on every run
and every machine. Pacing "realtime" additionally holds step k until wall time t_k / speed (for a real
board, whose UART and CPU then run at flight speed) and counts the CONTROL replies that arrive after the
next step was due.

Safety monitor (as an operator would): the flight is aborted when the vehicle tilts beyond
`abort_tilt_deg`, leaves the arena by more than `abort_margin_m`, strays `abort_error_m` from the
command, or the device refuses a SETPOINT.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

import numpy as np

from harness.closedloop.mission import MissionPlan
from harness.closedloop.sensors import Sensors, SensorConfig
from harness.closedloop.vehicle import Vehicle, VehicleParams
from harness.config import MODE_IMU, EstimatorConfig
from harness.device.channel import DeviceChannel, as_channel
from harness.errors import DeviceError, DeviceTimeout, UsageError
from harness.flight.arena import Arena
from harness.flight.measurement_errors import SimConfig
from harness.options import DEVICE_TIMEOUT_S
from protocol import messages as m

PACINGS = ("lockstep", "realtime")

@dataclass(frozen=True)
class LoopConfig:
    control_dt: float = 0.01        # s, SETPOINT/CONTROL period (the Crazyflie's position loop: 100 Hz)
    physics_dt: float = 0.002       # s, vehicle integration period (500 Hz, the Crazyflie's rate loop)
    imu_every: int = 1              # physics steps per IMU frame (the frame carries their average)
    pacing: str = "lockstep"
    speed: float = 1.0              # realtime pacing: simulated seconds per wall second
    timeout_s: float = DEVICE_TIMEOUT_S  # device silence before a step fails
    abort_tilt_deg: float = 60.0
    abort_margin_m: float = 0.5
    abort_error_m: float = 2.0

    def validate(self) -> None:
        if self.pacing not in PACINGS:
            raise UsageError(f"pacing must be one of {PACINGS}, got {self.pacing!r}")
        if not (0 < self.physics_dt <= self.control_dt):
            raise UsageError("need 0 < physics_dt <= control_dt")
        ratio = self.control_dt / self.physics_dt
        if self.imu_every < 1 or round(ratio) % self.imu_every:
            raise UsageError("imu_every must divide the physics steps per control step")
        if abs(ratio - round(ratio)) > 1e-9:
            raise UsageError("control_dt must be a whole number of physics steps")
        if round(self.control_dt * 1e6) % round(self.physics_dt * 1e6):
            raise UsageError("control_dt and physics_dt must be whole microseconds")
        if not self.speed > 0 or not self.timeout_s > 0:
            raise UsageError("speed and timeout_s must be > 0")


@dataclass
class FlightLog:
    """Per control step arrays (N rows) plus flight-level facts."""

    t: np.ndarray                 # (N,) s
    p_true: np.ndarray            # (N, 3)
    v_true: np.ndarray
    q_true: np.ndarray            # (N, 4)
    p_cmd: np.ndarray
    p_est: np.ndarray
    v_est: np.ndarray
    q_est: np.ndarray
    thrust: np.ndarray            # (N,) N
    rates: np.ndarray             # (N, 3) rad/s
    flags: np.ndarray             # (N,) control_flag bits
    motors_on: np.ndarray         # (N,) commanded mode POSITION
    ctl_on: np.ndarray            # (N,) the controller actually flew (CONTROL.mode)
    compute: np.ndarray           # (N,) device cost of the control step
    statuses: dict[str, int]      # RESULT status counts over the flight
    nlos_events: int
    errors: list[str] = field(default_factory=list)
    aborted: str | None = None    # why the safety monitor stopped the flight
    abort_t: float | None = None
    wall_s: float = 0.0
    late_controls: int = 0        # realtime pacing: CONTROL after the next step was due
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])


@dataclass
class _Craft:
    """One flight's physics and sensors, and what the device answered besides CONTROL."""
    vehicle: Vehicle
    sensors: Sensors
    statuses: dict[str, int] = field(default_factory=dict)
    errors: list[m.Error] = field(default_factory=list)


class ClosedLoop:
    """Flies missions through one started device (HELLO already checked): the physics, the pacing and the
    flight log; the frames go through the device's DeviceChannel."""

    def __init__(self, device: Any, loop: LoopConfig = LoopConfig()) -> None:
        """`device`: a DeviceChannel, or a started device (its `channel` is used)."""
        loop.validate()
        self.channel: DeviceChannel = as_channel(device)
        self.loop = loop

    def _await_control(self, seq: int, statuses: dict[str, int], errors: list[m.Error]) -> m.Control | None:
        """Read until the CONTROL for `seq` (returned) or an ERROR refusing it (None)."""
        deadline = time.monotonic() + self.loop.timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeout.for_request("SETPOINT", self.loop.timeout_s,
                                                f"seq {seq}; host decoder errors {self.channel.errors}")
            got = self.channel.read(min(left, 0.1))      # DeviceDied when the device is gone
            for status in got.results["status"].tolist():
                key = _STATUS_NAMES.get(status, f"status_{status}")
                statuses[key] = statuses.get(key, 0) + 1
            found: m.Control | None = None
            done = False
            for f in got.frames:
                if isinstance(f.msg, m.Control) and f.msg.setpoint_seq == seq:
                    found, done = f.msg, True
                elif isinstance(f.msg, m.Error):
                    errors.append(f.msg)
                    if f.msg.msg_seq == seq and f.msg.msg_type == m.Setpoint.MSG_ID:
                        done = True
            if done:
                return found

    def _advance(self, veh: Vehicle, sens: Sensors, t_us: int, thrust: float,
                 rates: tuple[float, float, float]) -> list[bytes]:
        """The physics steps of one control period ending at t_us with the last command, and the frames of
        the UWB measurements and (averaged) IMU samples that fell due in it."""
        lp = self.loop
        ctrl_us = int(round(lp.control_dt * 1e6))
        phys_us = int(round(lp.physics_dt * 1e6))
        chunks: list[bytes] = []
        f_sum = [0.0] * 6
        for j in range(1, ctrl_us // phys_us + 1):
            s = veh.state
            p_prev = (s.pos[0], s.pos[1], s.pos[2])
            veh.step(thrust, rates, lp.physics_dt)
            t_sub = t_us - ctrl_us + j * phys_us
            s = veh.state
            for idx, t_m in sens.due(t_sub - 1):
                w = (t_m - (t_sub - phys_us)) / phys_us   # position at the measurement time
                tag = tuple(p_prev[i] + (s.pos[i] - p_prev[i]) * w for i in range(3))
                u = sens.measure(idx, t_m, tag, s.quat)   # type: ignore[arg-type]
                chunks.append(self.channel.frame(_uwb(u))[0])
            sf, gy = veh.specific_force, veh.gyro
            for i in range(3):
                f_sum[i] += sf[i]
                f_sum[3 + i] += gy[i]
            if j % lp.imu_every == 0:
                c = 1.0 / lp.imu_every
                acc, gyr = sens.imu((f_sum[0] * c, f_sum[1] * c, f_sum[2] * c),
                                    (f_sum[3] * c, f_sum[4] * c, f_sum[5] * c))
                chunks.append(self.channel.frame(_imu(t_sub, acc, gyr))[0])
                f_sum = [0.0] * 6
        return chunks

    def _control_period(self, craft: _Craft, plan: MissionPlan, k: int, t_us: int,
                        command: tuple[float, tuple[float, float, float]],
                        wall0: float) -> tuple[m.Control | None, bool]:
        """Control period k ending at t_us under the last `command` (thrust, rates): the period's sensor frames
        and the k-th setpoint sent (at its wall time when pacing in real time), the device's CONTROL for it read
        back (None: refused), and whether it came later than the period's end. The statuses and ERRORs read on
        the way are added to `craft`."""
        lp = self.loop
        veh, sens, errors = craft.vehicle, craft.sensors, craft.errors
        if k == 0:
            acc, gyr = sens.imu(veh.specific_force, veh.gyro)
            chunks = [self.channel.frame(_imu(0, acc, gyr))[0]]
        else:
            chunks = self._advance(veh, sens, t_us, command[0], command[1])
        frame, seq = self.channel.frame(_setpoint(plan, k, t_us))
        chunks.append(frame)
        if lp.pacing == "realtime":
            due = wall0 + (t_us * 1e-6) / lp.speed
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
        self.channel.write(b"".join(chunks))
        ctl = self._await_control(seq, craft.statuses, errors)
        late = lp.pacing == "realtime" and time.perf_counter() > wall0 + (t_us * 1e-6 + lp.control_dt) / lp.speed
        if k == 0:
            refused = [e for e in errors if e.msg_type in (m.Config.MSG_ID, m.Anchor.MSG_ID)]
            if refused:
                raise DeviceError(f"device refused the flight setup: {refused[0]}")
        return ctl, late

    # ------------------------------------------------------------------------------------ flight
    def fly(self, plan: MissionPlan, est_cfg: EstimatorConfig, sensors_cfg: SensorConfig, sim: SimConfig,
            arena: Arena, vehicle: VehicleParams = VehicleParams(), seed: int = 1,
            progress: Callable[[int, int], None] | None = None) -> FlightLog:
        lp = self.loop
        start = plan.start
        veh = Vehicle(vehicle, pos=(start[0], start[1], vehicle.ground_z), yaw=float(plan.yaw[0]))
        sens = Sensors(sensors_cfg, sim, arena, seed, lp.physics_dt * lp.imu_every)
        cfg = est_cfg.with_init(start[0], start[1], vehicle.ground_z)
        if cfg.mode != MODE_IMU:
            raise UsageError("the closed loop needs the IMU estimator mode (the controller uses the attitude)")
        n = len(plan.t)
        log = _empty_log(n)
        craft = _Craft(veh, sens)
        errors = craft.errors
        ctrl_us = int(round(lp.control_dt * 1e6))
        lo, hi = np.asarray(arena.lo) - lp.abort_margin_m, np.asarray(arena.hi) + lp.abort_margin_m
        thrust, rates = 0.0, (0.0, 0.0, 0.0)
        self.channel.configure(cfg, arena.anchors, reset=True, timeout=lp.timeout_s)
        wall0 = time.perf_counter()
        late = 0
        aborted: str | None = None
        abort_t: float | None = None
        last = n
        for k in range(n):
            t_us = k * ctrl_us
            ctl, was_late = self._control_period(craft, plan, k, t_us, (thrust, rates), wall0)
            late += was_late
            s = veh.state
            _record(log, k, plan, s, ctl)
            if ctl is None:
                aborted, abort_t = f"device refused SETPOINT at t={t_us * 1e-6:.2f} s ({errors[-1]})", t_us * 1e-6
                last = k + 1
                break
            thrust = float(ctl.thrust)
            rates = (float(ctl.rate_x), float(ctl.rate_y), float(ctl.rate_z))
            reason = _safety(s.pos, s.quat, plan.pos[k], lo, hi, lp)
            if reason is not None:
                aborted, abort_t = reason, t_us * 1e-6
                last = k + 1
                break
            if progress is not None and k % 100 == 0:
                progress(k, n)
        wall = time.perf_counter() - wall0
        if last < n:
            log = _truncate(log, last)
        log.statuses = craft.statuses
        log.nlos_events = sens.nlos_events
        log.errors = [f"code {e.code} type {e.msg_type:#04x} seq {e.msg_seq} detail {e.detail}" for e in errors]
        log.aborted, log.abort_t = aborted, abort_t
        log.wall_s = wall
        log.late_controls = late
        log.meta = {"seed": seed, "mission": asdict(plan.mission), "sensors": asdict(sensors_cfg),
                    "estimator": asdict(cfg), "vehicle": asdict(vehicle), "loop": asdict(lp),
                    "profile": sim.name, "phases": {"t_takeoff": plan.t_takeoff, "t_main0": plan.t_main0,
                                                    "t_main1": plan.t_main1, "t_land": plan.t_land}}
        return log


_STATUS_NAMES = {int(m.Status.ACCEPTED): "accepted", int(m.Status.REJECTED_KINEMATIC): "rejected_kinematic",
                 int(m.Status.REJECTED_CHI2): "rejected_chi2", int(m.Status.REJECTED_GEOMETRY): "rejected_geometry",
                 int(m.Status.REJECTED_BASELINE): "rejected_baseline"}


def _setpoint(plan: MissionPlan, k: int, t_us: int) -> m.Setpoint:
    """The mission's k-th setpoint (motors off outside the flight)."""
    on = bool(plan.motors_on[k])
    return m.Setpoint(t_us=t_us, mode=int(m.ControlMode.POSITION if on else m.ControlMode.OFF), reserved=0,
                      x=float(plan.pos[k, 0]), y=float(plan.pos[k, 1]), z=float(plan.pos[k, 2]),
                      vx=float(plan.vel[k, 0]), vy=float(plan.vel[k, 1]), vz=float(plan.vel[k, 2]),
                      ax=float(plan.acc[k, 0]), ay=float(plan.acc[k, 1]), az=float(plan.acc[k, 2]),
                      yaw=float(plan.yaw[k]))


def _imu(t_us: int, acc: tuple[float, float, float], gyr: tuple[float, float, float]) -> m.Imu:
    return m.Imu(t_us=t_us, ax=acc[0], ay=acc[1], az=acc[2], gx=gyr[0], gy=gyr[1], gz=gyr[2])


def _uwb(u: Any) -> Any:
    if u.anchor_b < 0:
        return m.Twr(t_us=u.t_us, anchor_id=u.anchor_a, range=u.value)
    return m.Tdoa(t_us=u.t_us, anchor_a=u.anchor_a, anchor_b=u.anchor_b, diff=u.value)


def _safety(pos: list[float], quat: list[float], cmd: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            lp: LoopConfig) -> str | None:
    w, x, y, z = quat
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y)))))
    if tilt > lp.abort_tilt_deg:
        return f"tilt {tilt:.0f} deg > {lp.abort_tilt_deg:.0f} deg"
    if any(pos[i] < lo[i] or pos[i] > hi[i] for i in range(3)):
        return f"left the arena at ({pos[0]:.2f}, {pos[1]:.2f}, {pos[2]:.2f})"
    err = math.dist(pos, (float(cmd[0]), float(cmd[1]), float(cmd[2])))
    if err > lp.abort_error_m:
        return f"{err:.2f} m from the command"
    return None


def _empty_log(n: int) -> FlightLog:
    z3 = lambda: np.full((n, 3), np.nan)  # noqa: E731
    return FlightLog(t=np.full(n, np.nan), p_true=z3(), v_true=z3(), q_true=np.full((n, 4), np.nan), p_cmd=z3(),
                     p_est=z3(), v_est=z3(), q_est=np.full((n, 4), np.nan), thrust=np.full(n, np.nan),
                     rates=z3(), flags=np.zeros(n, np.uint8), motors_on=np.zeros(n, bool),
                     ctl_on=np.zeros(n, bool), compute=np.zeros(n, np.uint32), statuses={}, nlos_events=0)


def _record(log: FlightLog, k: int, plan: MissionPlan, s: Any, ctl: m.Control | None) -> None:
    log.t[k] = plan.t[k]
    log.p_true[k] = s.pos
    log.v_true[k] = s.vel
    log.q_true[k] = s.quat
    log.p_cmd[k] = plan.pos[k]
    log.motors_on[k] = plan.motors_on[k]
    if ctl is None:
        return
    log.p_est[k] = (ctl.px, ctl.py, ctl.pz)
    log.v_est[k] = (ctl.vx, ctl.vy, ctl.vz)
    log.q_est[k] = (ctl.qw, ctl.qx, ctl.qy, ctl.qz)
    log.thrust[k] = ctl.thrust
    log.rates[k] = (ctl.rate_x, ctl.rate_y, ctl.rate_z)
    log.flags[k] = ctl.flags
    log.ctl_on[k] = ctl.mode == int(m.ControlMode.POSITION)
    log.compute[k] = ctl.compute


def _truncate(log: FlightLog, n: int) -> FlightLog:
    out = {}
    for name, value in vars(log).items():
        out[name] = value[:n] if isinstance(value, np.ndarray) else value
    return FlightLog(**out)
