"""Range-offset calibration of TWR ranges: the bench procedure that sets a UWB radio's antenna delay.

A DW1000 range carries the antennas' and the radios' internal delays: a constant offset until the delay is
calibrated (ranging at known distances, then programming the difference). The rcv_twr recordings were made
uncalibrated: their ranges read +0.22 to +0.29 m long (median per sequence). `fit_range_offset` is that
calibration done on recordings with ground truth: the median of range - true range over every range of
the given flights (robust to the few gross errors), optionally per anchor. `apply_range_offset` subtracts
it from a flight's ranges before they are streamed, as a calibrated radio would have reported them.

Held out or not: a calibration records the flights it was fitted on, and applying it to one of them says
so (`held_out` false); the figures in docs/verdicts.md use leave-one-sequence-out calibrations only.
A per-anchor offset also takes what the anchors' placement does to their ranges (antenna pattern,
reflections); on rcv_twr it does not carry over between sequences (docs/verdicts.md), the global one does.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from harness.flight.data import KIND_TWR, Flight
from harness.errors import InputError

FORMAT = "uwb-hil range offset 1"


class RangeOffsetError(InputError):
    """A calibration that cannot be fitted, read or applied."""


@dataclass(frozen=True)
class RangeOffset:
    """Subtracted from TWR ranges [m]: `offset_m`, or per anchor id where `per_anchor_m` has one."""

    offset_m: float
    per_anchor_m: dict[int, float] = field(default_factory=dict)
    fitted_on: tuple[str, ...] = ()     # the flights' names (Flight.name)
    measurements: int = 0

    def for_anchors(self, anchor_ids: np.ndarray) -> np.ndarray:
        return np.array([self.per_anchor_m.get(int(a), self.offset_m) for a in anchor_ids], dtype=np.float64)

    def as_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, "offset_m": self.offset_m,
                "per_anchor_m": {str(k): v for k, v in sorted(self.per_anchor_m.items())},
                "fitted_on": list(self.fitted_on), "measurements": self.measurements}


def _errors(flight: Flight) -> np.ndarray:
    u = flight.uwb
    if u.kind != KIND_TWR:
        raise RangeOffsetError(f"{flight.name}: a range offset calibrates TWR ranges (in a TDoA difference a "
                               "common offset cancels)")
    if u.true_value is None:
        raise RangeOffsetError(f"{flight.name}: no true ranges (ground truth) to calibrate against")
    return np.asarray(u.value, dtype=np.float64) - np.asarray(u.true_value, dtype=np.float64)


def fit_range_offset(flights: Sequence[Flight], per_anchor: bool = False) -> RangeOffset:
    """The median range error over every range of `flights` (and per anchor id with `per_anchor`)."""
    if not flights:
        raise RangeOffsetError("no flight to fit the range offset on")
    errs = [_errors(f) for f in flights]
    ids = np.concatenate([f.uwb.anchor_a for f in flights])
    err = np.concatenate(errs)
    ok = np.isfinite(err)
    if not ok.any():
        raise RangeOffsetError("no finite range error to fit the range offset on")
    per: dict[int, float] = {}
    if per_anchor:
        per = {int(a): float(np.median(err[ok & (ids == a)])) for a in np.unique(ids[ok])}
    return RangeOffset(offset_m=float(np.median(err[ok])), per_anchor_m=per,
                       fitted_on=tuple(f.name for f in flights), measurements=int(ok.sum()))


def apply_range_offset(flight: Flight, cal: RangeOffset) -> Flight:
    """The flight with the offset subtracted from its ranges; meta records the calibration and whether
    this flight was held out of its fit."""
    if flight.uwb.kind != KIND_TWR:
        raise RangeOffsetError(f"{flight.name}: --range-offset applies to TWR ranges only")
    u = flight.uwb
    value = (np.asarray(u.value, dtype=np.float64) - cal.for_anchors(u.anchor_a)).astype(u.value.dtype)
    meta = {**flight.meta, "range_offset": {**cal.as_dict(), "held_out": flight.name not in cal.fitted_on}}
    return replace(flight, uwb=replace(u, value=value), meta=meta)


def save_range_offset(cal: RangeOffset, path: Path) -> None:
    Path(path).write_text(json.dumps(cal.as_dict(), indent=2) + "\n", encoding="utf-8")


def load_range_offset(path: Path) -> RangeOffset:
    """Read a calibration file (RangeOffsetError naming the file if it is not one)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RangeOffsetError(f"range offset file {path} not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RangeOffsetError(f"{path}: not a range offset file ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise RangeOffsetError(f"{path}: not a range offset file (expected \"format\": \"{FORMAT}\"; write one "
                               "with `uwb-hil range-offset --recording ... --out FILE`)")
    try:
        offset = float(data["offset_m"])
        per = {int(k): float(v) for k, v in dict(data.get("per_anchor_m") or {}).items()}
        fitted = tuple(str(x) for x in data.get("fitted_on") or ())
        n = int(data.get("measurements") or 0)
    except (KeyError, TypeError, ValueError) as exc:
        raise RangeOffsetError(f"{path}: malformed range offset file ({exc!r})") from None
    values = [offset, *per.values()]
    if not all(np.isfinite(v) and abs(v) <= 10.0 for v in values):
        raise RangeOffsetError(f"{path}: offsets must be finite and within +-10 m, got {values}")
    return RangeOffset(offset_m=offset, per_anchor_m=per, fitted_on=fitted, measurements=n)
