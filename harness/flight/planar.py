"""Planar mode: the tag's height is known (a ground robot, a tag at a fixed height, a height sensor), so
the host sends a HEIGHT pseudo-measurement before each UWB measurement and the firmware fuses it.

`--height Z` gives a constant height [m]; `--height truth` takes it from the recording's ground truth at
each measurement time (what a height sensor with the given std would report; for evaluating the planar
mode on recordings whose height varies). The std defaults to 5 cm.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from harness.errors import UsageError
from harness.flight.data import Flight, HeightStream

DEFAULT_HEIGHT_STD = 0.05


def parse_height(text: str) -> float | str:
    """'truth' or a finite number of metres; ValueError otherwise."""
    if text.strip().lower() == "truth":
        return "truth"
    try:
        z = float(text)
    except ValueError:
        raise UsageError(f"--height {text!r}: expected a height in metres or 'truth'") from None
    if not np.isfinite(z) or abs(z) > 1e4:
        raise UsageError(f"--height {text!r}: expected a finite height in metres (|z| <= 10 km)")
    return z


def with_height(flight: Flight, height: float | str, std: float = DEFAULT_HEIGHT_STD) -> Flight:
    """The flight with one HEIGHT pseudo-measurement at each UWB measurement time."""
    if not (np.isfinite(std) and 0 < std <= 1000):
        raise UsageError(f"--height-std must be in (0, 1000] m, got {std}")
    t = flight.uwb.t_us.astype(np.int64)
    if height == "truth":
        z = flight.truth.position_at(t)[:, 2]
    else:
        z = np.full(len(t), float(height))
    meta = {**flight.meta, "height": height if height == "truth" else float(height), "height_std": std}
    return replace(flight, height=HeightStream(t_us=t, z=z, std=float(std)), meta=meta)
