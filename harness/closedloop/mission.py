"""What the vehicle is commanded to fly: ground wait (motors off, the estimator settles), vertical take-off,
the paper's trajectory (circle at 0.375 m/s, planar or with varying height; or a hover), vertical landing,
motors off. The commanded path is the simulator's (harness/flight/trajectory.py: smooth take-off, speed
envelope), sampled at the control rate with velocity and acceleration feed-forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harness.flight.arena import Arena
from harness.flight.trajectory import Trajectory, circle_path, compose_flight, sample
from harness.errors import InputError

MISSIONS = ("hover", "circle", "circle-z")


class MissionError(InputError):
    """An impossible mission (unknown name, non-positive durations, leaves the arena)."""


@dataclass(frozen=True)
class Mission:
    name: str = "circle"
    height: float = 1.2           # m, circle / hover height
    radius: float = 2.0           # m
    speed: float = 0.375          # m/s, the paper's test speed
    z_amp: float | None = None    # m; None: 0.6 for circle-z, 0 otherwise
    z_cycles: float = 2.0         # height oscillations per lap (circle-z)
    laps: float = 1.0
    hover_s: float = 10.0         # main segment of "hover"
    ground_wait_s: float = 2.0    # motors off before take-off (and after landing)
    takeoff_s: float = 3.0        # vertical take-off (and landing) duration
    ramp_s: float = 2.0           # speed envelope at both ends of the main segment
    ground_z: float = 0.05        # tag height standing on the floor [m]

    def validate(self, arena: Arena | None = None) -> None:
        if self.name not in MISSIONS:
            raise MissionError(f"unknown mission {self.name!r}; choose one of {', '.join(MISSIONS)}")
        for f in ("height", "radius", "speed", "laps", "hover_s", "ground_wait_s", "takeoff_s"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0):
                raise MissionError(f"mission {f} must be > 0, got {v}")
        if self.ramp_s < 0 or self.height <= self.ground_z + 0.5:
            raise MissionError("ramp_s must be >= 0 and height above 0.5 m over the ground")
        if arena is not None:
            c = arena.center
            zamp = self.amplitude()
            lo, hi = np.asarray(arena.lo), np.asarray(arena.hi)
            r = self.radius if self.name != "hover" else 0.0
            if (c[0] - r < lo[0] or c[0] + r > hi[0] or c[1] - r < lo[1] or c[1] + r > hi[1]
                    or self.height + zamp > hi[2] or self.height - zamp < self.ground_z + 0.3):
                raise MissionError(f"mission {self.name} (radius {r} m, height {self.height}+-{zamp} m) "
                                   f"leaves the arena {tuple(lo)}..{tuple(hi)}")

    def amplitude(self) -> float:
        if self.name != "circle-z":
            return 0.0
        return 0.6 if self.z_amp is None else float(self.z_amp)

    def main_s(self) -> float:
        if self.name == "hover":
            return self.hover_s
        # the speed envelope loses ramp_s / 2 of travel at each end: add ramp_s to complete the laps
        return self.laps * 2.0 * math.pi * self.radius / self.speed + self.ramp_s


@dataclass(frozen=True)
class MissionPlan:
    """The commanded state at every control step and the phase boundaries [s]."""

    mission: Mission
    t: np.ndarray          # (N,) s
    pos: np.ndarray        # (N, 3)
    vel: np.ndarray
    acc: np.ndarray
    yaw: np.ndarray        # (N,)
    motors_on: np.ndarray  # (N,) bool
    t_takeoff: float       # take-off command
    t_main0: float         # start of the trajectory proper
    t_main1: float
    t_land: float          # landing complete (motors off after it)
    start: tuple[float, float, float]   # where the vehicle stands at t = 0

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


def plan(mission: Mission, arena: Arena, control_dt: float = 0.01) -> MissionPlan:
    mission.validate(arena)
    c = arena.center
    main_s = mission.main_s()
    if mission.name == "hover":
        point = np.array([c[0], c[1], mission.height])

        def path(tau: np.ndarray) -> np.ndarray:
            return np.repeat(point[None, :], tau.shape[0], axis=0)
    else:
        path = circle_path(np.array([c[0], c[1], mission.height]), mission.radius, mission.speed,
                           z_amp=mission.amplitude(), z_cycles=mission.z_cycles)

    def yaw(tau: np.ndarray) -> np.ndarray:
        return np.zeros(tau.shape[0])

    traj: Trajectory = compose_flight(mission.name, path, yaw, main_s, mission.ramp_s, mission.ground_z,
                                      takeoff_s=mission.takeoff_s, ground_wait_s=mission.ground_wait_s)
    n = int(math.floor(traj.duration / control_dt + 1e-9)) + 1
    t = np.arange(n) * control_dt
    s = sample(traj, t)
    t_takeoff = mission.ground_wait_s
    t_main0 = t_takeoff + mission.takeoff_s
    t_main1 = t_main0 + main_s
    t_land = t_main1 + mission.takeoff_s
    # Take-off and landing ends: the finite differences of `sample` straddle the clamp at t = 0 / end;
    # the vehicle is at rest there.
    on = (t >= t_takeoff - 1e-9) & (t <= t_land + 1e-9)
    vel, acc = s.vel.copy(), s.acc.copy()
    vel[~on] = 0.0
    acc[~on] = 0.0
    for box in arena.boxes:
        # the obstacles of the "nlos" arena stand on the floor: a vehicle cannot fly through one
        lo, hi = np.asarray(box.lo), np.asarray(box.hi)
        inside = np.all((s.pos >= lo - 0.1) & (s.pos <= hi + 0.1), axis=1)
        if np.any(inside):
            k = int(np.argmax(inside))
            raise MissionError(f"mission {mission.name} passes through the obstacle {box.lo}..{box.hi} at "
                               f"t = {t[k]:.1f} s ({s.pos[k, 0]:.2f}, {s.pos[k, 1]:.2f}, {s.pos[k, 2]:.2f}); "
                               f"choose another radius or height")
    start = tuple(float(v) for v in s.pos[0])
    return MissionPlan(mission=mission, t=t, pos=s.pos, vel=vel, acc=acc, yaw=traj.yaw(t), motors_on=on,
                       t_takeoff=t_takeoff, t_main0=t_main0, t_main1=t_main1, t_land=t_land,
                       start=(start[0], start[1], start[2]))
