"""`uwb-hil tune`: pick estimator settings on training recordings by a grid search, for `run --set @FILE.toml`.

Every combination of the grid's values is replayed over every recording through the numpy twin of the
firmware (harness/twin: the same estimator as the device within the core-vs-twin tests' tolerances, and ~100x
faster than streaming through a device: a 30 s Crazyflie flight with its IMU in ~3 s), scored by the mean
3-D position RMSE over the flight phase (truth above ``flight_above``). A combination under which the filter
diverged (a supervisor reset) on any recording is ranked after every one that did not, whatever its RMSE:
a setting that needs the supervisor is not a setting. The pick goes to a settings file with its provenance.

Tune on training flights only and evaluate the pick on flights it never saw: the score here is an
in-sample figure.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from harness.config import PRESETS, EstimatorConfig, config_with
from harness.errors import InputError
from harness.flight.data import FLIGHT_ABOVE_M, Flight
from harness.flight.run_config import config_for
from harness.twin.estimator import FLAG_DIVERGED, run_flight


@dataclass(frozen=True)
class GridAxis:
    """One CONFIG field and the values tried."""

    field: str
    values: tuple[float, ...]

    @classmethod
    def parse(cls, text: str) -> "GridAxis":
        """From `FIELD=V1,V2,...` (checked against CONFIG's fields and bounds by config_with)."""
        name, sep, rest = text.partition("=")
        if not sep or not name.strip() or not rest.strip():
            raise InputError(f"--grid {text!r}: expected FIELD=V1,V2,...")
        values: list[float] = []
        for item in rest.split(","):
            try:
                values.append(float(item))
            except ValueError:
                raise InputError(f"--grid {text!r}: {item!r} is not a number") from None
        for v in values:
            try:
                config_with([f"{name.strip()}={v}"])    # unknown field or out of bounds -> InputError naming it
            except InputError as exc:                  # named as the option the user typed, not --set
                message = str(exc)
                raise InputError(f"--grid {text!r}: " + (message.split(": ", 1)[-1] if message.startswith("--set")
                                                          else message)) from None
        return cls(name.strip(), tuple(dict.fromkeys(values)))


@dataclass(frozen=True)
class Trial:
    """One combination's outcome over the recordings."""

    settings: tuple[tuple[str, float], ...]
    rmse_m: tuple[float, ...]       # per recording, flight phase
    resets: tuple[int, ...]         # supervisor resets per recording

    @property
    def mean_rmse_m(self) -> float:
        return float(np.mean(self.rmse_m))

    @property
    def diverged(self) -> bool:
        return any(self.resets)

    def as_dict(self) -> dict[str, Any]:
        return {"settings": dict(self.settings), "mean_rmse_m": self.mean_rmse_m, "rmse_m": list(self.rmse_m),
                "resets": list(self.resets)}


def flight_rmse(flight: Flight, positions: np.ndarray, flight_above: float) -> float:
    """3-D RMSE of ``positions`` (one per UWB measurement) against the truth above ``flight_above``."""
    truth = flight.truth.position_at(flight.uwb.t_us)
    m = truth[:, 2] > flight_above
    if not np.any(m):
        raise InputError(f"{flight.name}: the truth is never above {flight_above} m: no flight phase to score")
    e = positions[m] - truth[m]
    return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))


def run_trial(flights: Sequence[Flight], preset: str, base: Sequence[str], combo: tuple[tuple[str, float], ...],
              flight_above: float, uwb_only: bool = False, model: object | None = None) -> Trial:
    """Replay every flight with the base settings plus ``combo`` through the twin."""
    settings = config_with([*base, *(f"{k}={v}" for k, v in combo)])
    rmse, resets = [], []
    for f in flights:
        res = run_flight(f, config_for(f, settings, stages=PRESETS[preset], uwb_only=uwb_only), model)
        pos = np.array([r.pos for r in res]) if res else np.zeros((0, 3))
        rmse.append(flight_rmse(f, pos, flight_above))
        resets.append(sum(1 for r in res if r.flags & FLAG_DIVERGED))
    return Trial(combo, tuple(rmse), tuple(resets))


def grid_search(flights: Sequence[Flight], axes: Sequence[GridAxis], preset: str, base: Sequence[str] = (),
                flight_above: float = FLIGHT_ABOVE_M, uwb_only: bool = False, model: object | None = None,
                log: Callable[[str], None] | None = None) -> list[Trial]:
    """Every combination of the axes, ranked: no resets first, then by mean RMSE. `log` gets one progress line
    per combination (a grid of many combinations over long flights runs for minutes)."""
    if not flights:
        raise InputError("tune: no recordings")
    if preset not in PRESETS:
        raise InputError(f"tune: unknown stages {preset!r} (one of {', '.join(PRESETS)})")
    names = [a.field for a in axes]
    if len(set(names)) != len(names):
        raise InputError(f"tune: a field is gridded twice ({', '.join(names)})")
    both = sorted({item.partition("=")[0].strip() for item in base if not item.startswith("@")} & set(names))
    if both:        # a settings file (@FILE) may be re-gridded on a field; a --set typed with it is overridden
        raise InputError(f"tune: {', '.join(both)} given both by --set and --grid (the grid would override "
                         "--set): drop one")
    combos = [tuple(zip(names, values)) for values in itertools.product(*(a.values for a in axes))]
    trials, t0 = [], time.monotonic()
    for k, combo in enumerate(combos, start=1):
        trials.append(run_trial(flights, preset, base, combo, flight_above, uwb_only, model))
        if log is not None:
            el = time.monotonic() - t0
            log(f"[{k}/{len(combos)}, {el:.0f} s, ETA {el / k * (len(combos) - k):.0f} s] "
                f"{', '.join(f'{n}={v:g}' for n, v in combo)}: mean RMSE {trials[-1].mean_rmse_m:.4f} m, "
                f"{sum(trials[-1].resets)} resets")
    return sorted(trials, key=lambda t: (t.diverged, t.mean_rmse_m))


def settings_toml(best: Trial, recordings: Sequence[str], preset: str, base: Sequence[str],
                  trials: int) -> str:
    """The pick as a settings file (`run --set @FILE`): every field the base settings and the pick move from
    the power-up values, the provenance in comments."""
    chosen = vars(config_with([*base, *(f"{k}={v}" for k, v in best.settings)]))
    power_up = vars(EstimatorConfig())
    moved = [(k, float(v)) for k, v in chosen.items() if v != power_up[k]]
    lines = ["# Picked by `uwb-hil tune` (grid search through the firmware's numpy twin) on:",
             *(f"#   {r}" for r in recordings),
             f"# stages {preset}; base settings: {', '.join(base) if base else 'the power-up values'};"
             f" {trials} combinations tried.",
             f"# In-sample mean flight-phase 3-D RMSE {best.mean_rmse_m:.4f} m; supervisor resets "
             f"{sum(best.resets)}. Evaluate it on flights it was not picked on.",
             "", "[settings]"]
    lines += [f"{k} = {v!r}" for k, v in moved]
    return "\n".join(lines) + "\n"


def write_settings(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
