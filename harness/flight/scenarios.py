"""Simulated flights: `scenario_flight(name, mode, ...)` -> Flight (truth, 1 kHz IMU, TWR or TDoA stream).

Scenarios (paper's arena, see harness/flight/arena.py):
  circle     horizontal circle at 0.375 m/s (the paper's test trajectory), radius 2 m, 1.2 m high
  circle-z   the same circle with height varying +-0.6 m (two cycles per lap)
  random     smooth random 3-D path with a wandering yaw (training data)
  spin       spin in place (yaw rate `spin_dps`, default 30 deg/s), the paper's Fig. 2/5 experiment
  hover      hold a point
Every flight starts and ends at rest (speed envelope); `takeoff=True` adds ground wait, take-off and
landing inside `duration_s` (campaign flights: 60-80 s with take-off).

Noise: "none" (exact values, perfect IMU), "gaussian" (N(0, noise_std) on every measurement, IMU noise),
"realistic" (the calibrated error model of harness/flight/measurement_errors.py, profile "los" or "nlos").
Same arguments and seed -> identical arrays.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np

from harness.flight.arena import NLOS_BOXES, Arena, default_anchors
from harness.flight.chunked import IMU_RATE_HZ, SimPlan
from harness.flight.measurement_errors import SimConfig, sim_config
from harness.flight.data import KIND_TDOA, KIND_TWR, Anchors, Flight
from harness.flight.trajectory import Trajectory, circle_path, compose_flight, random_path
from harness.errors import InputError

SCENARIOS = ("circle", "circle-z", "random", "spin", "hover")
NOISE_KINDS = ("none", "gaussian", "realistic")
MODES = ("twr", "tdoa", "tdoa2", "tdoa3")



class ScenarioError(InputError):
    """Unknown scenario, mode, noise kind or option."""


DEFAULT_TAKEOFF_S = 4.0
DEFAULT_GROUND_WAIT_S = 1.0
MIN_MAIN_S = 0.5          # the scenario itself, between take-off and landing


def min_duration_s(takeoff: bool, takeoff_s: float = DEFAULT_TAKEOFF_S,
                   ground_wait_s: float = DEFAULT_GROUND_WAIT_S) -> float:
    """Shortest duration_s a scenario accepts (exclusive bound): callers validate options with it up front."""
    return (2.0 * (takeoff_s + ground_wait_s) if takeoff else 0.0) + MIN_MAIN_S


def _trajectory(name: str, duration_s: float, rng: np.random.Generator, arena: Arena,
                kw: dict[str, Any]) -> Trajectory:
    takeoff = bool(kw.pop("takeoff", False))
    ramp = float(kw.pop("ramp_s", 2.0))
    takeoff_s = float(kw.pop("takeoff_s", DEFAULT_TAKEOFF_S))
    wait_s = float(kw.pop("ground_wait_s", DEFAULT_GROUND_WAIT_S))
    ground_z = float(kw.pop("ground_z", 0.05)) if takeoff else None
    main_s = duration_s - (min_duration_s(takeoff, takeoff_s, wait_s) - MIN_MAIN_S)
    if main_s <= MIN_MAIN_S:
        raise ScenarioError(f"duration_s={duration_s} too short for scenario {name!r} "
                            f"(needs > {min_duration_s(takeoff, takeoff_s, wait_s):.1f} s)")
    ramp = min(ramp, main_s / 4.0)   # short flights: shorter speed ramps
    center = arena.center
    height = float(kw.pop("height", 1.2))
    speed = float(kw.pop("speed", 0.375))
    radius = float(kw.pop("radius", 2.0))
    yaw0 = float(kw.pop("yaw", 0.0))

    if name in ("circle", "circle-z"):
        z_amp = float(kw.pop("z_amp", 0.6 if name == "circle-z" else 0.0))
        path = circle_path(np.array([center[0], center[1], height]), radius, speed, z_amp=z_amp,
                           z_cycles=float(kw.pop("z_cycles", 2.0)))
        yaw_path = _const_yaw(yaw0)
    elif name == "random":
        margin = float(kw.pop("margin", 0.8))
        lo = np.array([arena.lo[0] + margin, arena.lo[1] + margin, float(kw.pop("z_min", 0.5))])
        hi = np.array([arena.hi[0] - margin, arena.hi[1] - margin, float(kw.pop("z_max", 2.3))])
        path = random_path(rng, lo, hi)
        yaw_path = _random_yaw(rng, yaw0, float(kw.pop("yaw_amp", 2.5)))
    elif name == "spin":
        point = np.array(kw.pop("point", (center[0] + 0.5, center[1] - 0.5, height)), dtype=np.float64)
        rate = np.deg2rad(float(kw.pop("spin_dps", 30.0)))
        path = _const_point(point)
        yaw_path = _linear_yaw(yaw0, rate)
    elif name == "hover":
        point = np.array(kw.pop("point", (center[0], center[1], height)), dtype=np.float64)
        path = _const_point(point)
        yaw_path = _const_yaw(yaw0)
    else:
        raise ScenarioError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    return compose_flight(name, path, yaw_path, main_s, ramp, ground_z, takeoff_s=takeoff_s, ground_wait_s=wait_s)


def _const_point(p: np.ndarray):  # noqa: ANN202
    return lambda tau: np.repeat(p[None, :], tau.shape[0], axis=0)


def _const_yaw(y: float):  # noqa: ANN202
    return lambda tau: np.full(tau.shape[0], y)


def _linear_yaw(y0: float, rate: float):  # noqa: ANN202
    return lambda tau: y0 + rate * tau


def _random_yaw(rng: np.random.Generator, y0: float, amp: float):  # noqa: ANN202
    f = rng.uniform(0.01, 0.06, size=3)
    ph = rng.uniform(0, 2 * np.pi, size=3)
    a = amp * rng.dirichlet(np.ones(3))
    return lambda tau: y0 + np.sum(a[None, :] * (np.sin(2 * np.pi * f[None, :] * tau[:, None] + ph[None, :])
                                                 - np.sin(ph[None, :])), axis=1)


def _schedule(mode: str, anchors: Anchors, duration_s: float, rate_hz: float, rng: np.random.Generator,
              jitter: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurement times [us] and anchor ids: TWR round-robin; TDoA2 consecutive pairs (N-1,0),(0,1),...;
    TDoA3 random distinct pairs. Times are periodic with a small uniform jitter (radio scheduling)."""
    period_us = 1e6 / rate_hz
    n = int(np.floor((duration_s * 1e6 - period_us) / period_us))
    base = period_us * (1 + np.arange(n))
    t = base + rng.uniform(-jitter, jitter, size=n) * period_us
    t_us = np.round(t).astype(np.int64)
    ids = anchors.ids
    k = len(ids)
    if mode == "twr":
        a = ids[np.arange(n) % k]
        b = np.full(n, -1, dtype=np.int64)
    elif mode in ("tdoa", "tdoa2"):
        j = np.arange(n) % k
        a = ids[(j - 1) % k]
        b = ids[j]
    else:  # tdoa3
        ia = rng.integers(0, k, size=n)
        ib = (ia + rng.integers(1, k, size=n)) % k
        a, b = ids[ia], ids[ib]
    return t_us, a.astype(np.int64), b.astype(np.int64)


def plan_scenario(name: str, mode: str = "twr", duration_s: float = 30.0, seed: int = 1,
                  noise: str = "realistic", noise_std: float = 0.1, **kw: Any) -> SimPlan:
    """Everything of a simulated flight but its arrays (see scenario_flight for the options)."""
    if mode not in MODES:
        raise ScenarioError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")
    if noise not in NOISE_KINDS:
        raise ScenarioError(f"unknown noise {noise!r}; choose one of {', '.join(NOISE_KINDS)}")
    if not (duration_s > 0 and np.isfinite(duration_s)):
        raise ScenarioError(f"duration_s must be positive, got {duration_s}")
    if not (noise_std >= 0 and np.isfinite(noise_std)):
        raise ScenarioError(f"noise_std must be >= 0, got {noise_std}")
    kw = dict(kw)
    profile = str(kw.pop("profile", "los"))
    cfg: SimConfig = kw.pop("config", None) or sim_config(profile)
    anchors: Anchors | None = kw.pop("anchors", None)
    boxes = kw.pop("boxes", NLOS_BOXES if cfg.obstacles else ())
    arena = Arena(anchors=anchors if anchors is not None else default_anchors(), boxes=tuple(boxes))
    rate_hz = float(kw.pop("rate_hz", 200.0 if mode == "twr" else 400.0))
    if not 1.0 <= rate_hz <= 5000.0:
        raise ScenarioError(f"rate_hz must be in [1, 5000], got {rate_hz}")
    options = {k: v for k, v in kw.items() if isinstance(v, (int, float, str, bool))}

    # Independent streams per purpose: changing the noise kind does not move the trajectory or schedule.
    ss = np.random.SeedSequence(seed)
    rng_traj, rng_sched, rng_uwb, rng_imu = (np.random.default_rng(s) for s in ss.spawn(4))

    traj = _trajectory(name, duration_s, rng_traj, arena, kw)
    if kw:
        raise ScenarioError(f"unknown option(s) for scenario {name!r}: {', '.join(sorted(kw))}")
    total_s = traj.duration
    kind_mode = "twr" if mode == "twr" else ("tdoa3" if mode == "tdoa3" else "tdoa2")
    t_us, a_ids, b_ids = _schedule(kind_mode, arena.anchors, total_s, rate_hz, rng_sched, cfg.schedule_jitter)

    meta: dict[str, object] = {
        "source": "simulator", "scenario": name, "mode": kind_mode, "seed": seed, "noise": noise,
        "duration_s": total_s, "rate_hz": rate_hz, "imu_rate_hz": IMU_RATE_HZ, "options": options,
    }
    if noise == "gaussian":
        meta["noise_std"] = noise_std
    if noise == "realistic":
        meta["profile"] = cfg.name
        meta["sim_config"] = asdict(cfg)
        meta["obstacles"] = [asdict(b) for b in arena.boxes]
    # Truth and IMU at 1 kHz over the whole flight (covers every measurement time), measurement-time
    # truth exact, attitude interpolated from the 1 kHz truth: built by SimPlan, whole or in slices.
    return SimPlan(name=f"sim-{name}-{kind_mode}-{noise}-s{seed}", arena=arena, traj=traj, cfg=cfg,
                   kind=KIND_TWR if kind_mode == "twr" else KIND_TDOA, noise=noise, noise_std=noise_std,
                   sched_t=t_us, sched_a=a_ids, sched_b=b_ids, rng_uwb=rng_uwb, rng_imu=rng_imu, meta=meta)


def scenario_flight(name: str, mode: str = "twr", duration_s: float = 30.0, seed: int = 1,
                    noise: str = "realistic", noise_std: float = 0.1, **kw: Any) -> Flight:
    """A simulated flight, built whole (`plan_scenario(...).chunks()` builds the same flight in slices).
    Options (kw): profile ("los" | "nlos"), config (a SimConfig overriding the profile), anchors
    (Anchors), rate_hz (UWB rate, default 200 TWR / 400 TDoA), takeoff, ramp_s, takeoff_s,
    ground_wait_s, height, speed, radius, yaw, z_amp, spin_dps, point, margin, z_min, z_max."""
    return plan_scenario(name, mode, duration_s, seed, noise, noise_std, **kw).whole()


__all__ = ["min_duration_s", "SCENARIOS", "NOISE_KINDS", "MODES", "ScenarioError", "plan_scenario", "scenario_flight"]
