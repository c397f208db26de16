"""Estimator configuration shared by the firmware (CONFIG message) and the numpy twin."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

from protocol.messages import EkfMode, Stage

# Protocol enums ekf_mode and stage (protocol/messages.toml), as plain ints.
MODE_IMU = int(EkfMode.IMU)
MODE_UWB_ONLY = int(EkfMode.UWB_ONLY)
STAGE_BIAS_NN = int(Stage.BIAS_NN)
STAGE_KINEMATIC_GATE = int(Stage.KINEMATIC_GATE)
STAGE_CHI2_GATE = int(Stage.CHI2_GATE)
STAGE_NN_STD = int(Stage.NN_STD)                # measurement std = the network's predicted std (when it runs)
STAGE_ROBUST_UPDATE = int(Stage.ROBUST_UPDATE)  # M-estimation weights on the update (robust_update.c)
STAGE_NN_MONITOR = int(Stage.NN_MONITOR)        # per-pair monitor switching a harmful correction off (nn_monitor.c)
STAGES_ALL = STAGE_BIAS_NN | STAGE_KINEMATIC_GATE | STAGE_CHI2_GATE  # the paper's outlier rejection + network
STAGES_OUTLIER = STAGE_KINEMATIC_GATE | STAGE_CHI2_GATE
STAGES_VALID = STAGES_ALL | STAGE_NN_STD | STAGE_ROBUST_UPDATE | STAGE_NN_MONITOR  # every bit CONFIG may set
FLOAT32_MAX = 3.4028234663852886e38   # largest finite IEEE-754 single (the CONFIG frame's field type)

#: The three configurations of the paper's experiments, then the alternatives of issue 14: the network's
#: std as the measurement std, and the robust update in place of the chi-square gate.
PRESETS: dict[str, int] = {
    "none": 0,
    "outlier": STAGES_OUTLIER,
    "outlier+nn": STAGES_ALL,
    "outlier+nn+std": STAGES_ALL | STAGE_NN_STD,
    "outlier+nn+monitor": STAGES_ALL | STAGE_NN_MONITOR,
    "robust": STAGE_KINEMATIC_GATE | STAGE_ROBUST_UPDATE,
    "robust+nn": STAGE_KINEMATIC_GATE | STAGE_ROBUST_UPDATE | STAGE_BIAS_NN,
}
#: What campaigns fly by default (the paper's table); the others are asked for by name.
PAPER_PRESETS: tuple[str, ...] = ("none", "outlier", "outlier+nn")


class ConfigError(ValueError):
    """An estimator configuration value is out of range."""


@dataclass(frozen=True)
class EstimatorConfig:
    """What CONFIG carries. Defaults are the firmware's power-up values (firmware_sim/core/estimator.c)."""

    mode: int = MODE_IMU
    stages: int = STAGES_ALL
    std_twr: float = 0.25
    std_tdoa: float = 0.15
    # Kinematic gate: d_max = |v| dt + a_max dt^2 / 2 with dt >= gate_dt_min. Like the paper's on-board
    # code (a_max = 4 T_max g), a_max is a tuned bound, not a physical acceleration.
    a_max_twr: float = 5000.0
    a_max_tdoa: float = 5000.0
    gate_dt_min: float = 0.01
    chi2_twr: float = 3.841
    chi2_tdoa: float = 3.841
    proc_acc_xy: float = 0.5
    proc_acc_z: float = 1.0
    proc_cv_acc: float = 2.0
    init_x: float = 0.0
    init_y: float = 0.0
    init_z: float = 0.0
    init_std_xy: float = 1.0
    init_std_z: float = 1.0
    nn_min_z: float = 0.5
    # Supervisor (as the Crazyflie's): a position outside the anchors' bounding box widened by sup_margin
    # [m], a speed above sup_max_speed [m/s] or a position variance above sup_max_var [m^2] (never below
    # the initial variance) re-initialises the filter and reports DIVERGED (docs/ARCHITECTURE.md).
    sup_margin: float = 10.0
    sup_max_speed: float = 10.0
    sup_max_var: float = 50.0

    def validate(self) -> None:
        """Raise ConfigError naming the first invalid field (the firmware refuses the same values)."""
        if self.mode not in (MODE_IMU, MODE_UWB_ONLY):
            raise ConfigError(f"mode must be {MODE_IMU} (IMU) or {MODE_UWB_ONLY} (UWB-only), got {self.mode}")
        if self.stages & ~STAGES_VALID:
            raise ConfigError(f"stages has unknown bits: {self.stages:#x}")
        for name, value in asdict(self).items():
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(f"{name} must be finite, got {value}")
            if isinstance(value, float) and abs(value) > FLOAT32_MAX:    # the CONFIG frame carries float32
                raise ConfigError(f"{name} = {value:g} does not fit the device's 32-bit float "
                                  f"(|value| <= {FLOAT32_MAX:.4g})")
        positive = ("std_twr", "std_tdoa", "a_max_twr", "a_max_tdoa", "gate_dt_min", "chi2_twr",
                    "chi2_tdoa", "proc_cv_acc", "init_std_xy", "init_std_z", "sup_max_speed", "sup_max_var")
        for name in positive:
            if getattr(self, name) <= 0.0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("proc_acc_xy", "proc_acc_z", "sup_margin"):
            if getattr(self, name) < 0.0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")

    def with_stages(self, stages: int) -> "EstimatorConfig":
        return replace(self, stages=stages)

    def with_init(self, x: float, y: float, z: float) -> "EstimatorConfig":
        return replace(self, init_x=float(x), init_y=float(y), init_z=float(z))
