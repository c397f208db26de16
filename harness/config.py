"""Estimator configuration shared by the firmware (CONFIG message) and the numpy twin.

The fields, their defaults, units and bounds are defined once, on the CONFIG message in
protocol/messages.toml; `python -m protocol.generate` makes EstimatorConfigBase (the dataclass and its
validate()) and the firmware's C struct, defaults and checks from them. Here: the helpers and presets.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

from protocol.messages import ConfigError as ProtocolConfigError
from protocol.messages import EkfMode, EstimatorConfigBase, Stage

from harness.errors import InputError, UsageError

# Protocol enums ekf_mode and stage (protocol/messages.toml), as plain ints.
MODE_IMU = int(EkfMode.IMU)
MODE_UWB_ONLY = int(EkfMode.UWB_ONLY)
MODE_IMU_THRUST = int(EkfMode.IMU_THRUST)   # IMU mode for a quadrotor (thrust-axis accelerometer only)
STAGE_BIAS_NN = int(Stage.BIAS_NN)
STAGE_KINEMATIC_GATE = int(Stage.KINEMATIC_GATE)
STAGE_CHI2_GATE = int(Stage.CHI2_GATE)
STAGE_NN_STD = int(Stage.NN_STD)                # measurement std = the network's predicted std (when it runs)
STAGE_ROBUST_UPDATE = int(Stage.ROBUST_UPDATE)  # M-estimation weights on the update (robust_update.c)
STAGE_NN_MONITOR = int(Stage.NN_MONITOR)        # per-pair monitor switching a harmful correction off (nn_monitor.c)
STAGE_BIAS_STATES = int(Stage.BIAS_STATES)      # per-anchor Gauss-Markov bias states (bias_states.c)
STAGES_ALL = STAGE_BIAS_NN | STAGE_KINEMATIC_GATE | STAGE_CHI2_GATE  # the paper's outlier rejection + network
STAGES_OUTLIER = STAGE_KINEMATIC_GATE | STAGE_CHI2_GATE

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
    "outlier+states": STAGES_OUTLIER | STAGE_BIAS_STATES,    # the states alone (no usable network)
    "outlier+nn+states": STAGES_ALL | STAGE_BIAS_STATES,
    "outlier+nn+std+states": STAGES_ALL | STAGE_NN_STD | STAGE_BIAS_STATES,
    "robust+nn+states": STAGE_KINEMATIC_GATE | STAGE_ROBUST_UPDATE | STAGE_BIAS_NN | STAGE_BIAS_STATES,
}
#: What campaigns fly by default (the paper's table); the others are asked for by name.
PAPER_PRESETS: tuple[str, ...] = ("none", "outlier", "outlier+nn")


class ConfigError(UsageError, ProtocolConfigError):
    """An estimator configuration value out of range (the device would refuse it): an input error, exit 2."""


@dataclass(frozen=True)
class EstimatorConfig(EstimatorConfigBase):
    """What CONFIG carries: the generated fields (defaults = the firmware's power-up values) and validate().
    Kinematic gate: d_max = |v| dt + a_max dt^2 / 2 with dt >= gate_dt_min. Supervisor: a position outside
    the anchors' box widened by sup_margin, a speed above sup_max_speed or a position variance above
    sup_max_var re-initialises the filter (docs/ARCHITECTURE.md)."""

    def validate(self) -> None:
        """ConfigError naming the first invalid field (the device refuses the same values)."""
        try:
            super().validate()
        except ProtocolConfigError as exc:
            raise ConfigError(str(exc)) from None

    def with_stages(self, stages: int) -> "EstimatorConfig":
        return replace(self, stages=stages)

    def with_init(self, x: float, y: float, z: float) -> "EstimatorConfig":
        return replace(self, init_x=float(x), init_y=float(y), init_z=float(z))


def settings_file(path: str | Path) -> list[str]:
    """The ``[settings]`` table of a settings file (e.g. harness/settings/*.toml) as ``FIELD=VALUE`` items:
    a documented, named set of estimator overrides instead of --set flags typed by hand."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"settings file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"settings file {path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"settings file {path}: {exc}") from None
    table = data.get("settings")
    if not isinstance(table, dict) or not table:
        raise InputError(f"settings file {path}: no [settings] table of FIELD = VALUE")
    # a key above the [settings] header would otherwise be dropped without a word (other tables, e.g. a
    # [source] with provenance, are the file's own business)
    stray = [k for k, v in data.items() if not isinstance(v, dict)]
    if stray:
        raise InputError(f"settings file {path}: {', '.join(stray)} outside the [settings] table")
    for k, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise InputError(f"settings file {path}: {k} = {v!r} is not a number")
    return [f"{k}={v}" for k, v in table.items()]


def config_with(settings: Sequence[str]) -> EstimatorConfig:
    """EstimatorConfig() with `FIELD=VALUE` overrides (numeric fields; mode, stages and the initial position
    come from their own options and the flight). An item `@FILE.toml` stands for that file's settings
    (settings_file); later items win."""
    allowed = [k for k in vars(EstimatorConfig()) if k not in ("mode", "stages", "init_x", "init_y", "init_z")]
    overrides: dict[str, float] = {}
    items: list[tuple[str, str]] = []      # (FIELD=VALUE, where it was given: --set or the settings file)
    for item in settings:
        items += [(x, f"settings file {item[1:]}: ") for x in settings_file(item[1:])] if item.startswith("@") \
            else [(item, "--set ")]
    for item, where in items:
        name, sep, text = item.partition("=")
        if not sep or name.strip() not in allowed:
            raise InputError(f"{where}{item!r}: expected FIELD=VALUE with FIELD one of {', '.join(allowed)}")
        try:
            overrides[name.strip()] = float(text)
        except ValueError:
            raise InputError(f"{where}{item!r}: {text!r} is not a number") from None
    cfg = replace(EstimatorConfig(), **overrides)
    cfg.validate()
    return cfg
