"""One place that turns user choices (target, port, scenario, recording) into devices and flights."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator
from contextlib import contextmanager

from harness.config import MODE_IMU, MODE_UWB_ONLY, EstimatorConfig
from harness.flight.data import KIND_TDOA, KIND_TWR, Flight

from harness.paths import DEFAULT_FIRMWARE, DEFAULT_STM32_ELF, REPO_ROOT, SHARED_DATA  # noqa: F401 (re-exported)

TARGETS = ("emulator", "serial", "qemu")


@dataclass(frozen=True)
class DeviceSpec:
    target: str = "emulator"
    port: str | None = None
    baud: int = 115200
    firmware: Path | None = None     # None: the target's default (host binary, or the STM32 ELF for qemu)
    timeout_s: float = 5.0
    log_dir: Path | None = None
    flash_cmd: str | None = None     # run (shell) before the device starts, e.g. to flash the board
    flash_timeout_s: float = 600.0

    def resolved_target(self) -> str:
        return "serial" if (self.port and self.target == "emulator") else self.target

    def firmware_path(self) -> Path:
        if self.firmware is not None:
            return Path(self.firmware)
        return DEFAULT_STM32_ELF if self.resolved_target() == "qemu" else DEFAULT_FIRMWARE


@contextmanager
def open_device(spec: DeviceSpec, expected_model_hash: int | None = None) -> Iterator[object]:
    """Start (or connect to) the device, check its HELLO, and always stop it."""
    target = spec.resolved_target()
    firmware = spec.firmware_path()
    if target == "emulator":
        from harness.device.emulator import EmulatorDevice
        if not firmware.is_file():
            raise FileNotFoundError(f"firmware binary {firmware} not found: run `make firmware`")
        device = EmulatorDevice(firmware, log_dir=spec.log_dir)
    elif target == "serial":
        from harness.device.serial_device import SerialDevice, SerialDeviceOptions
        if not spec.port:
            raise ValueError("target 'serial' needs a port (--port /dev/ttyACM0, rfc2217://host:port, ...)")
        # --timeout bounds writes too: a board (or serial server) that stops reading fails the run
        device = SerialDevice(spec.port, spec.baud, SerialDeviceOptions(write_timeout_s=spec.timeout_s))
    elif target == "qemu":
        try:
            from harness.device.qemu import QemuDevice  # type: ignore[import-not-found]
        except ImportError:
            raise NotImplementedError("the QEMU target is not available in this build") from None
        if not firmware.is_file():    # checked here: a missing ELF is a usage error (exit 2), not a device failure
            raise FileNotFoundError(f"firmware ELF {firmware} not found: build it with `make stm32` "
                                    "or pass --firmware PATH")
        device = QemuDevice(elf=firmware, log_dir=spec.log_dir)
    else:
        raise ValueError(f"unknown target {target!r}; choose one of {TARGETS}")
    if spec.flash_cmd:
        from harness.device.flash import run_flash_command
        log = Path(spec.log_dir) / "flash.log" if spec.log_dir else None
        run_flash_command(spec.flash_cmd, spec.flash_timeout_s, log)
    device.start()
    try:
        device.hello(timeout=spec.timeout_s)
        device.check(expected_model_hash=expected_model_hash)
        yield device
    finally:
        device.stop()


def config_for(flight: Flight, base: EstimatorConfig | None = None, stages: int | None = None,
               uwb_only: bool | None = None) -> EstimatorConfig:
    """Estimator configuration for a flight: start at its first true position, IMU mode if it has IMU."""
    cfg = base or EstimatorConfig()
    p0 = flight.truth.position_at([int(flight.uwb.t_us[0])])[0] if len(flight.uwb) else (0.0, 0.0, 0.0)
    mode = MODE_UWB_ONLY if (uwb_only or not flight.has_imu) else MODE_IMU
    cfg = replace(cfg, mode=mode).with_init(*p0)
    if stages is not None:
        cfg = cfg.with_stages(stages)
    return cfg


def kind_name(kind: int) -> str:
    return {KIND_TWR: "twr", KIND_TDOA: "tdoa"}[kind]


def shared_data_dir() -> Path:
    return Path(os.environ.get("UWB_HIL_DATA", SHARED_DATA))


#: position-only networks trained on the shared recordings (`make models`), by measurement kind (the
#: rcv_twr network takes the attitude: there is no shipped position-only TWR network)
POSITION_ONLY_MODELS = {KIND_TDOA: "firmware_sim/models/util_tdoa_pos.npz"}


def position_only_hint(kind: int) -> str:
    """Where to get a network without attitude inputs for this measurement kind."""
    train = f"train one with `uwb-hil train --recording ... --layout pos --out {kind_name(kind)}_pos.npz`"
    if kind in POSITION_ONLY_MODELS:
        return f"--model {POSITION_ONLY_MODELS[kind]} (built by `make models`), or {train}"
    return train


def check_network_inputs(flight: Flight, cfg: EstimatorConfig, layouts: tuple[int, int]) -> None:
    """Refuse to run a bias network that takes the attitude (pose layout) where the firmware has none: a
    UWB-only replay (no IMU, or --uwb-only) feeds it a level attitude, and its correction is then made up.
    `layouts` = the device's (TWR, TDoA) network layouts from HELLO."""
    from harness.config import STAGE_BIAS_NN
    from harness.errors import InputError
    from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE
    if not cfg.stages & STAGE_BIAS_NN or cfg.mode != MODE_UWB_ONLY:
        return
    kind = flight.uwb.kind
    layout = layouts[0] if kind == KIND_TWR else layouts[1]
    if layout not in (LAYOUT_TWR_POSE, LAYOUT_TDOA_POSE):
        return
    why = "has no IMU" if not flight.has_imu else "is replayed with --uwb-only"
    raise InputError(f"the device's {kind_name(kind).upper()} bias network takes roll, pitch and yaw (pose layout "
                     f"{layout}), but {flight.name} {why}: the firmware has no attitude to give it and its correction "
                     f"would be made up. Use a position-only network ({position_only_hint(kind)}), or --stages outlier, or "
                     "pass --force to run it anyway")
