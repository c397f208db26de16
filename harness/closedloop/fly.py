"""What `uwb-hil fly` does: closed-loop flights (modes x missions x configurations x seeds) through one
device; the command (harness/closedloop/cli.py) parses its options and prints the result. (Not to be
confused with harness/campaign/, the open-loop experiments of `uwb-hil campaign`.)"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

from harness.closedloop.cosim import ClosedLoop, FlightLog, LoopConfig
from harness.closedloop.metrics import aggregate, flight_metrics
from harness.closedloop.mission import Mission, plan
from harness.closedloop.sensors import SensorConfig
from harness.closedloop.vehicle import VehicleParams
from harness.kinds import check_network_present
from harness.config import MODE_IMU, PAPER_PRESETS, PRESETS, EstimatorConfig
from harness.flight.arena import NLOS_BOXES, Arena
from harness.flight.measurement_errors import sim_config
from harness.device.registry import DeviceSpec, open_device


@dataclass(frozen=True)
class FlySpec:
    """A closed-loop campaign; its defaults are `uwb-hil fly`'s (the mission's and vehicle's from their own
    dataclasses)."""
    modes: tuple[str, ...] = ("twr", "tdoa")
    missions: tuple[str, ...] = ("circle", "circle-z")
    configs: tuple[str, ...] = PAPER_PRESETS
    seeds: tuple[int, ...] = tuple(range(1, 11))
    laps: float = Mission.laps
    hover_s: float = Mission.hover_s
    radius: float = Mission.radius
    height: float = Mission.height
    profile: str = "los"
    noise: str = "realistic"
    mass: float = VehicleParams.mass
    loop: LoopConfig = LoopConfig()
    estimator: EstimatorConfig = EstimatorConfig()


Progress = Callable[[str], None]


def fly_cells(device: Any, spec: FlySpec, progress: Progress | None = None,
                 keep_logs: bool = False) -> dict[str, Any]:
    """Fly every cell; returns {"cells": [...]} with aggregates and per-flight metrics."""
    sim = sim_config(spec.profile)
    arena = Arena(boxes=NLOS_BOXES if sim.obstacles else ())
    vehicle = VehicleParams(mass=spec.mass)
    loop = ClosedLoop(device, spec.loop)
    cells = []
    for mode in spec.modes:
        for mission_name in spec.missions:
            pl = plan(_mission(spec, mission_name), arena, spec.loop.control_dt)
            for config in spec.configs:
                est = replace(spec.estimator, mode=MODE_IMU).with_stages(PRESETS[config])
                logs: list[FlightLog] = []
                per: list[dict[str, Any]] = []
                for seed in spec.seeds:
                    log = loop.fly(pl, est, SensorConfig(mode=mode, noise=spec.noise), sim, arena, vehicle, seed)
                    fm = flight_metrics(log)
                    fm["seed"] = seed
                    per.append(fm)
                    logs.append(log)
                    if progress is not None:
                        progress(f"{mode:4s} {mission_name:8s} {config:10s} seed {seed:3d}: "
                                 f"take-off {'ok ' if fm['takeoff']['success'] else 'FAIL'} "
                                 f"tracking {fm['tracking_rmse']:.3f} m, estimation {fm['estimation_rmse']:.3f} m"
                                 + (f", aborted: {fm['aborted']}" if fm["aborted"] else "")
                                 + f" ({fm['wall_s']:.1f} s)")
                cell = {"mode": mode, "mission": mission_name, "config": config, **aggregate(logs, per),
                        "per_flight": per}
                if keep_logs:
                    cell["logs"] = logs
                cells.append(cell)
    return {"cells": cells, "spec": _spec_dict(spec), "mission_duration_s": {
        name: plan(_mission(spec, name), arena).duration for name in spec.missions}}


def fly_on_device(device_spec: DeviceSpec, want_hash: int | None, spec: FlySpec,
                  progress: Progress | None = None) -> dict[str, Any]:
    """fly_cells on the device `device_spec` describes (which must carry the model `want_hash` when given);
    the result's `device` is its identity."""
    with open_device(device_spec, expected_model_hash=want_hash) as device:
        hello = device.identity.as_dict()
        for mode in spec.modes:
            for config in spec.configs:
                check_network_present(mode, PRESETS[config], device.identity.layouts, f"--config {config}")
        result = fly_cells(device, spec, progress)
    result["device"] = hello
    return result


def _mission(spec: FlySpec, name: str) -> Mission:
    return Mission(name=name, laps=spec.laps, hover_s=spec.hover_s, radius=spec.radius, height=spec.height)


def _spec_dict(spec: FlySpec) -> dict[str, Any]:
    from dataclasses import asdict
    d = asdict(spec)
    d["seeds"] = list(spec.seeds)
    return d
