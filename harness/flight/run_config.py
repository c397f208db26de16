"""The estimator configuration a flight runs with (`config_for`: IMU or UWB-only mode, the initial position, the
stages), and the check that the device's bias network can run on it (its inputs need the attitude)."""

from __future__ import annotations

from dataclasses import replace

from harness.config import MODE_IMU, MODE_IMU_THRUST, MODE_UWB_ONLY, EstimatorConfig
from harness.flight.data import KIND_TDOA, KIND_TWR, Flight


def config_for(flight: Flight, base: EstimatorConfig | None = None, stages: int | None = None,
               uwb_only: bool | None = None) -> EstimatorConfig:
    """Estimator configuration for a flight: start at its first true position, IMU mode if it has IMU (the
    quadrotor model, MODE_IMU_THRUST, for a flight whose meta says `vehicle: quadrotor`, as a Crazyflie log)."""
    cfg = base or EstimatorConfig()
    p0 = flight.truth.position_at([int(flight.uwb.t_us[0])])[0] if len(flight.uwb) else (0.0, 0.0, 0.0)
    imu_mode = MODE_IMU_THRUST if flight.meta.get("vehicle") == "quadrotor" else MODE_IMU
    mode = MODE_UWB_ONLY if (uwb_only or not flight.has_imu) else imu_mode
    cfg = replace(cfg, mode=mode).with_init(*p0)
    if stages is not None:
        cfg = cfg.with_stages(stages)
    return cfg


def kind_name(kind: int) -> str:
    return {KIND_TWR: "twr", KIND_TDOA: "tdoa"}[kind]


#: position-only networks trained on the shared recordings (`make models`), by measurement kind (the
#: rcv_twr network takes the attitude: there is no shipped position-only TWR network)
POSITION_ONLY_MODELS = {KIND_TDOA: "firmware_sim/models/util_tdoa_pos.npz"}


def position_only_hint(kind: int) -> str:
    """Where to get a network without attitude inputs for this measurement kind."""
    train = f"train one with `uwb-hil train --recording ... --layout pos --out {kind_name(kind)}_pos.npz`"
    if kind in POSITION_ONLY_MODELS:
        return f"--model {POSITION_ONLY_MODELS[kind]} (built by `make models`), or {train}"
    return train


def takes_attitude(layout: int) -> bool:
    """Whether a network of this input layout takes roll, pitch and yaw (which a UWB-only replay lacks)."""
    from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE
    return layout in (LAYOUT_TWR_POSE, LAYOUT_TDOA_POSE)


def check_network_inputs(flight: Flight, cfg: EstimatorConfig, layouts: tuple[int, int]) -> None:
    """Refuse to run a bias network that takes the attitude (pose layout) where the firmware has none: a
    UWB-only replay (no IMU, or --uwb-only) feeds it a level attitude, and its correction is then made up.
    `layouts` = the device's (TWR, TDoA) network layouts from HELLO."""
    from harness.config import STAGE_BIAS_NN
    from harness.errors import InputError
    if not cfg.stages & STAGE_BIAS_NN or cfg.mode != MODE_UWB_ONLY:
        return
    kind = flight.uwb.kind
    layout = layouts[0] if kind == KIND_TWR else layouts[1]
    if not takes_attitude(layout):
        return
    why = "has no IMU" if not flight.has_imu else "is replayed with --uwb-only"
    raise InputError(f"the device's {kind_name(kind).upper()} bias network takes roll, pitch and yaw (pose layout "
                     f"{layout}), but {flight.name} {why}: the firmware has no attitude to give it and its correction "
                     f"would be made up. Use a position-only network ({position_only_hint(kind)}), or --stages outlier, or "
                     "pass --force to run it anyway")
