"""Checks of one CONFIG field, used by the generated EstimatorConfigBase.validate() (protocol/_generated.py).

The table of fields (defaults, units, bounds) is generated from protocol/messages.toml; the firmware's
estimator_config_valid() (generated too) applies the same bounds to the float32 values it receives, so
the bounds here are checked on the value rounded to float32.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

FLOAT32_MAX = 3.4028234663852886e38   # largest finite IEEE-754 single (the CONFIG frame's field type)


class ConfigError(ValueError):
    """An estimator configuration value is out of range (the device would refuse it: ERROR BAD_CONFIG)."""


@dataclass(frozen=True)
class ConfigField:
    """One CONFIG field as messages.toml defines it. ge/gt/le/lt: >=, >, <=, < bounds (None: none);
    choices: the (name, value) pairs an enum field may take; mask: the bits a flags field may set."""

    name: str
    wire: str                  # "u8" | "f32"
    default: float | int
    unit: str = ""
    doc: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[tuple[str, int], ...] | None = None
    mask: int | None = None
    control: bool = False      # a field of the message (CONFIG.reset), not of the configuration

    def bounds_text(self) -> str:
        """The bounds as `> 0`, `>= 0, <= 1` (empty when none)."""
        parts = [f"{op} {v:g}" for op, v in ((">=", self.ge), (">", self.gt), ("<=", self.le), ("<", self.lt))
                 if v is not None]
        return ", ".join(parts)


def as_float32(value: float) -> float:
    """``value`` rounded to IEEE-754 single, as the device receives it."""
    return float(struct.unpack("<f", struct.pack("<f", value))[0])


def _check_int(f: ConfigField, value: object) -> None:
    if not isinstance(value, int) or not 0 <= value <= 255:
        raise ConfigError(f"{f.name} must be an integer in 0..255, got {value!r}")
    if f.choices is not None and value not in {v for _, v in f.choices}:
        names = ", ".join(f"{n}={v}" for n, v in f.choices)
        raise ConfigError(f"{f.name} must be one of {names}, got {value}")
    if f.mask is not None and value & ~f.mask:
        raise ConfigError(f"{f.name} has unknown bits: {value & ~f.mask:#x} (valid: {f.mask:#x})")


def check_field(f: ConfigField, value: object) -> None:
    """Raise ConfigError if ``value`` is not a valid value of field ``f``."""
    if f.wire != "f32":
        _check_int(f, value)
        x: float = float(value)  # type: ignore[arg-type]
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{f.name} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{f.name} must be finite, got {value}")
        if abs(value) > FLOAT32_MAX:
            raise ConfigError(f"{f.name} = {value:g} does not fit the device's 32-bit float "
                              f"(|value| <= {FLOAT32_MAX:.4g})")
        x = as_float32(float(value))
    if ((f.ge is not None and not x >= f.ge) or (f.gt is not None and not x > f.gt)
            or (f.le is not None and not x <= f.le) or (f.lt is not None and not x < f.lt)):
        unit = f" {f.unit}" if f.unit else ""
        raise ConfigError(f"{f.name} must be {f.bounds_text()}{unit}, got {value}")
