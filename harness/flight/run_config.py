"""The one place a run's estimator configuration is assembled: `run_estimator_config` (the power-up values, the
run's settings, its preset's stages, the flight's mode and initial position) for `uwb-hil run`, `demo`, a
campaign run; `config_for` is its flight-dependent part, for callers that start from a configuration."""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from harness.config import MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, PRESETS, EstimatorConfig, config_with
from harness.flight.data import Flight


def config_for(flight: Flight, base: EstimatorConfig | None = None, stages: int | None = None,
               uwb_only: bool | None = None) -> EstimatorConfig:
    """Estimator configuration for a flight: start at its first true position, IMU mode if it has IMU (the
    quadrotor model, MODE_IMU_THRUST, for a flight whose meta says `vehicle: quadrotor`, as a Crazyflie log; such
    a flight with IMU gets floor_imu = 1 in every mode, UWB-only included)."""
    cfg = base or EstimatorConfig()
    p0 = flight.truth.position_at([int(flight.uwb.t_us[0])])[0] if len(flight.uwb) else (0.0, 0.0, 0.0)
    quadrotor = flight.meta.get("vehicle") == "quadrotor"
    mode = MODE_UWB_ONLY if (uwb_only or not flight.has_imu) else (MODE_IMU_THRUST if quadrotor else MODE_IMU)
    # a quadrotor log starts on the floor: its IMU tells when it sits there, in every mode (core/takeoff.h)
    floor_imu = int(quadrotor and flight.has_imu) or cfg.floor_imu
    cfg = replace(cfg, mode=mode, floor_imu=floor_imu).with_init(*p0)
    if flight.aux is not None and "tof_offset_m" in flight.meta:   # the ranger's offset from the state's point
        tx, ty, tz = (float(v) for v in flight.meta["tof_offset_m"])   # type: ignore[attr-defined]
        cfg = replace(cfg, tof_x=tx, tof_y=ty, tof_z=tz)
    if stages is not None:
        cfg = cfg.with_stages(stages)
    return cfg


def run_estimator_config(flight: Flight, preset: str, settings: Sequence[str] = (),
                         uwb_only: bool = False) -> EstimatorConfig:
    """The estimator configuration of a run: the CONFIG power-up values with `settings` applied (FIELD=VALUE or
    @FILE.toml, harness.config.config_with), the stages of `preset` (a key of harness.config.PRESETS), and the
    flight's mode and initial position (config_for)."""
    return config_for(flight, config_with(settings), stages=PRESETS[preset], uwb_only=uwb_only)
