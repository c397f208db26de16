"""Where training flights come from: simulated recipes and the shared recordings, split by flight.

Simulated training flights use seeds below :data:`FIRST_EVAL_SEED`; evaluation flights (campaign,
closed loop) use seeds from it upwards, so the network is always judged on flights it never saw.
UTIL: train on const1/const2 trials 1-4 (tdoa2 and tdoa3 files), hold out trial 5. const3 is another
anchor constellation (with obstacles): the features are anchor-relative positions of anchors the network
never saw, so it is no test of the network (the paper leaves other constellations to future work).
rcv_twr: train on sequences 1-4, hold out sequence 5.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from harness.errors import UsageError
from harness.flight.data import Flight
from harness.flight.formats.cf_usd_flight import UsdOptions

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


def load_recordings(paths: list[Path], anchors: Path | None = None, check: bool = True,
                    usd: UsdOptions = UsdOptions()) -> list[Flight]:
    """Load recordings; check=False (--force) skips the plausibility checks (harness/flight/plausibility.py);
    `usd`: how Crazyflie uSD logs are read (--ignore-crc, --lever-arm)."""
    from harness.flight.loaders import load_recording
    return [load_recording(p, anchors, check=check, usd=usd) for p in paths]
