"""argparse value types that refuse out-of-range options at parse time (exit code 2, argparse's one-line
usage error naming the option) instead of letting them fail deep inside a run or be silently accepted
(`--baud 0`, `--timeout -1`, `--duration 1e9` allocating terabytes)."""

from __future__ import annotations

import argparse
import math
from typing import Callable

#: a board's serial line speed when none is given (the firmware's UWB_BAUD default, firmware_sim/stm32/Makefile)
DEFAULT_BAUD = 115200
#: seconds of device silence before a command, a fixture or a replay gives up (`--timeout`, `--uwb-timeout`,
#: DeviceSpec, the streamer, the closed loop)
DEVICE_TIMEOUT_S = 5.0
#: seconds of device silence before a campaign's run fails (`uwb-hil campaign --timeout`'s default)
CAMPAIGN_TIMEOUT_S = 10.0
#: longest simulated flight `run`/`demo` build [s]: 4 h (a 1 h flight is ~3 GB built whole today)
MAX_SIM_DURATION_S = 4 * 3600.0
#: real-time pacing speed factor (harness/stream/streamer.py's Pacing): at most 100 times slower than real
#: time, a million times faster (a speed of 1e-300 would pace for ever)
MIN_SPEED, MAX_SPEED = 0.01, 1e6


def number(kind: type, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           unit: str = "") -> Callable[[str], float | int]:
    """An int or finite float within [lo, hi] ((lo, hi] when lo_open)."""
    def parse(text: str) -> float | int:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        too_low = lo is not None and (value <= lo if lo_open else value < lo)
        too_high = hi is not None and value > hi
        if too_low or too_high:
            lower = "" if lo is None else (f"> {lo:g}" if lo_open else f">= {lo:g}")
            upper = "" if hi is None else f"<= {hi:g}"
            bounds = " and ".join(b for b in (lower, upper) if b)
            raise argparse.ArgumentTypeError(f"must be {bounds}{unit}, got {text}")
        return value
    parse.__name__ = kind.__name__     # argparse names the type in "invalid <type> value" messages
    return parse


non_negative_int = number(int, 0)
#: highest serial line speed accepted (--baud, a board list's baud)
MAX_BAUD = 100_000_000
baud = number(int, 1, MAX_BAUD, unit=" baud")
timeout_s = number(float, 0.0, 86_400.0, lo_open=True, unit=" s")
sim_duration_s = number(float, 0.0, MAX_SIM_DURATION_S, lo_open=True, unit=" s")
window = number(int, 1, 1024)
speed = number(float, MIN_SPEED, MAX_SPEED)
#: a threshold or bound in metres that must be positive (`--xi`), a height that may be negative (`--flight-above`)
positive_m = number(float, 0.0, lo_open=True, unit=" m")
height_m = number(float, -1000.0, 1000.0, unit=" m")

#: largest |component| of a tag lever arm [m] (a Crazyflie-sized vehicle; a mistyped mm value is refused)
MAX_LEVER_ARM_M = 1.0


def lever_arm(text: str) -> tuple[float, float, float] | str:
    """'x,y,z' in metres (body frame), each component within +-MAX_LEVER_ARM_M; or a calibration FILE.json
    written by `uwb-hil lever-arm` (returned as its path: the reader loads it)."""
    if text.strip().lower().endswith(".json"):
        return text.strip()
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z in metres (3 numbers), got {text!r}")
    parse = number(float, -MAX_LEVER_ARM_M, MAX_LEVER_ARM_M, unit=" m")
    x, y, z = (float(parse(p)) for p in parts)
    return (x, y, z)


def add_recording_read_options(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """Options of the binary recordings' readers, for every command that takes --recording (the values go to
    harness.flight.loaders.UsdOptions.make)."""
    p.add_argument("--ignore-crc", action="store_true",
                   help="Crazyflie uSD logs: load a log whose CRC-32 does not match (still reported as a warning)")
    p.add_argument("--lever-arm", type=lever_arm, metavar="X,Y,Z|FILE.json",
                   help="Crazyflie uSD logs: vehicle origin -> UWB tag in the body frame [m], or a calibration "
                        "fitted by `uwb-hil lever-arm` (default: UTIL's Crazyflie, -0.01245,0.00127,0.0908)")
