"""Where training flights come from: simulated recipes and the shared recordings, split by flight.

Simulated training flights use seeds below :data:`FIRST_EVAL_SEED`; evaluation flights (campaign,
closed loop) use seeds from it upwards, so the network is always judged on flights it never saw.
UTIL: train on const1/const2 trials 1-4 (tdoa2 and tdoa3 files), hold out trial 5. const3 is another
anchor constellation (with obstacles): the features are anchor-relative positions of anchors the network
never saw, so it is no test of the network (the paper leaves other constellations to future work).
rcv_twr: train on sequences 1-4, hold out sequence 5.
Crazyflie uSD logs (cf_usd/, IMU + TDoA + pose with attitude): the line-of-sight flights of 0425 (1-8 TDoA2,
13-18 TDoA3) minus a fixed evaluation set, flights 3 and 8 (TDoA2) and 13 and 18 (TDoA3), never trained on;
the shelf flights of 0426 (3: TDoA2, 5: TDoA3; non-line-of-sight) are never trained on by the shipped network.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

from harness.errors import UsageError
from harness.flight.data import Flight
from harness.flight.formats.cf_usd_flight import UsdOptions
from harness.flight.formats.cf_usd_summary import FileStamp, file_stamp

FIRST_EVAL_SEED = 1000


@dataclass(frozen=True)
class SimRecipe:
    """Simulated training data: random 3-D flights plus spins in place (yaw coverage), LOS profile."""

    mode: str = "twr"            # twr | tdoa
    flights: int = 24
    duration_s: float = 120.0
    spins: int = 4               # of the flights, how many are spins in place
    seed0: int = 0
    profile: str = "los"

    def seeds(self) -> range:
        if self.seed0 + self.flights > FIRST_EVAL_SEED:
            raise UsageError(f"training seeds must stay below {FIRST_EVAL_SEED} (evaluation seeds)")
        return range(self.seed0, self.seed0 + self.flights)

    def flight(self, seed: int) -> Flight:
        from harness.flight.scenarios import scenario_flight
        name = "spin" if (seed - self.seed0) < self.spins else "random"
        duration = min(self.duration_s, 40.0) if name == "spin" else self.duration_s
        return scenario_flight(name, mode=self.mode, duration_s=duration, seed=seed, profile=self.profile)

    def build(self, progress: Callable[[int, int], None] | None = None) -> list[Flight]:
        out = []
        seeds = list(self.seeds())
        for k, s in enumerate(seeds):
            out.append(self.flight(s))
            if progress is not None:
                progress(k + 1, len(seeds))
        return out


#: The flights the compiled-in network's std head is fitted on (`make models`, and `uwb-hil fit-std`'s
#: defaults): seeds 500-503, neither the training seeds (SimRecipe's 0-23) nor evaluation seeds (>= 1000).
STD_HEAD_RECIPE = SimRecipe(flights=4, duration_s=120.0, spins=1, seed0=500)


def util_files(data: Path, trials: tuple[int, ...], constellations: tuple[int, ...] = (1, 2),
               variants: tuple[str, ...] = ("tdoa2", "tdoa3")) -> list[Path]:
    """UTIL reduced CSVs of the given trials that exist under ``data``/util."""
    out = []
    for c in constellations:
        for t in trials:
            for v in variants:
                p = data / "util" / f"const{c}" / f"const{c}-trial{t}-{v}-extracted.csv"
                if p.is_file():
                    out.append(p)
    return out


def util_train_files(data: Path) -> list[Path]:
    return util_files(data, (1, 2, 3, 4))


def util_heldout_files(data: Path) -> list[Path]:
    return util_files(data, (5,))


def rcv_sequences(data: Path, numbers: tuple[int, ...]) -> list[Path]:
    return [p for p in (data / "rcv_twr" / f"sequence{n}" for n in numbers) if p.is_dir()]


def rcv_train_dirs(data: Path) -> list[Path]:
    return rcv_sequences(data, (1, 2, 3, 4))


def rcv_heldout_dirs(data: Path) -> list[Path]:
    return rcv_sequences(data, (5,))


#: Crazyflie uSD flights, relative to the data folder: line of sight (0425: flights 1-8 TDoA2, 13-18 TDoA3),
#: the evaluation flights among them, and the shelf flights (0426, non-line-of-sight)
CF_USD_TDOA2 = (1, 2, 3, 4, 5, 6, 7, 8)
CF_USD_TDOA3 = (13, 14, 15, 16, 17, 18)
CF_USD_EVAL_FLIGHTS = (3, 8, 13, 18)
CF_USD_LOS = tuple(f"cf_usd/0425/0425-traj{n}" for n in (*CF_USD_TDOA2, *CF_USD_TDOA3))
CF_USD_EVAL = tuple(f"cf_usd/0425/0425-traj{n}" for n in CF_USD_EVAL_FLIGHTS)
CF_USD_SHELF = ("cf_usd/0426/0426-traj3", "cf_usd/0426/0426-traj5")


def cf_usd_files(data: Path, rels: tuple[str, ...]) -> list[Path]:
    return [p for p in (data / r for r in rels) if p.is_file()]


def cf_usd_train_files(data: Path) -> list[Path]:
    """The LOS flights minus the evaluation ones, TDoA2 and TDoA3 alternating (1, 14, 2, 15, ...): the
    distilled ensemble's teacher k is validated on training flight k (a uSD flight is its own group)."""
    tdoa2 = [n for n in CF_USD_TDOA2 if n not in CF_USD_EVAL_FLIGHTS]
    tdoa3 = [n for n in CF_USD_TDOA3 if n not in CF_USD_EVAL_FLIGHTS]
    mixed = [n for pair in zip(tdoa2, tdoa3) for n in pair] + tdoa2[len(tdoa3):] + tdoa3[len(tdoa2):]
    return cf_usd_files(data, tuple(f"cf_usd/0425/0425-traj{n}" for n in mixed))


def cf_usd_heldout_files(data: Path) -> list[Path]:
    return cf_usd_files(data, CF_USD_EVAL)


def cf_usd_shelf_files(data: Path) -> list[Path]:
    return cf_usd_files(data, CF_USD_SHELF)


#: a tag lever arm, body frame [m]
LeverArm = tuple[float, float, float]


def cf_usd_lever_arms(data: Path) -> dict[str, LeverArm]:
    """The tag's lever arm every shared uSD flight is read with (flight name -> body-frame metres), calibrated
    as `uwb-hil lever-arm` does on flights other than the evaluated ones: a 0425 flight takes the fit on the
    0425 training flights (training and evaluation flights alike; the network is trained on that tag point),
    a shelf flight the fit on the other shelf flight (the vehicle was set up anew on 0426). Empty without
    the shared data. The logs are loaded and fitted once per process while they and their anchor files are
    unchanged (_fitted_lever_arms)."""
    from harness.flight.loaders import find_usd_anchor_file
    train, shelf = cf_usd_train_files(data), cf_usd_shelf_files(data)
    if not train:
        return {}
    logs = (*train, *shelf)
    anchor_files = sorted({a for a in map(find_usd_anchor_file, logs) if a is not None})
    day0425, shelf_fits = _fitted_lever_arms(tuple(train), tuple(shelf),
                                             tuple(file_stamp(p) for p in (*logs, *anchor_files)))
    out = {p.name: day0425 for p in (*train, *cf_usd_heldout_files(data))}
    out.update(shelf_fits)
    return out


# lru_cache on a function of the files and their identity (FileStamp: path, size, mtime_ns; `stamps` only keys
# the cache) rather than a cache object: the campaign plan, `make real-flights` and the shipped-model checks each
# ask for the same fits; the cache is bounded and no module-level state of ours. Its values are immutable tuples.
@lru_cache(maxsize=8)
def _fitted_lever_arms(train: tuple[Path, ...], shelf: tuple[Path, ...], stamps: tuple[FileStamp, ...]
                       ) -> tuple[LeverArm, tuple[tuple[str, LeverArm], ...]]:
    """(the fit on the 0425 training flights, (shelf flight name, the fit on the other shelf flight) ...)."""
    from harness.flight.lever_arm import fit_lever_arm
    from harness.flight.loaders import load_recordings
    day0425 = fit_lever_arm(load_recordings(train)).lever_arm_m
    shelf_fits = tuple((p.name, fit_lever_arm(load_recordings(others)).lever_arm_m)
                       for p in shelf if (others := [q for q in shelf if q != p]))
    return day0425, shelf_fits


def load_cf_usd_calibrated(paths: list[Path], levers: dict[str, tuple[float, float, float]]) -> list[Flight]:
    """uSD logs read with their calibrated lever arm (cf_usd_lever_arms; UTIL's when a flight has none)."""
    from harness.flight.loaders import load_recording
    return [load_recording(p, usd=UsdOptions.make(lever_arm=levers.get(p.name))) for p in paths]
