"""UTIL TDoA groups: the real trials and simulated flights in the same constellations."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from harness.calibrate.stats import CalibrationError, ErrorStats, error_stats
from harness.flight.arena import with_facing_orientations
from harness.flight.data import Anchors
from harness.flight.measurement_errors import SimConfig, sim_config


@dataclass(frozen=True)
class UtilGroup:
    name: str
    pattern: str          # glob under util/
    mode: str             # tdoa2 | tdoa3
    profile: str
    rate_hz: float


UTIL_GROUPS = (
    UtilGroup("LOS TDoA2 (const1+const2)", "const[12]/*-tdoa2-*.csv", "tdoa2", "los", 475.0),
    UtilGroup("LOS TDoA3 (const1)", "const1/*-tdoa3-*.csv", "tdoa3", "los", 280.0),
    UtilGroup("NLOS TDoA2 (const3)", "const3/*-tdoa2-*.csv", "tdoa2", "nlos", 450.0),
)


def _constellation_of(path: Path) -> int:
    name = path.name
    if not name.startswith("const") or not name[5:6].isdigit():
        raise CalibrationError(f"{path}: cannot tell the constellation from the file name (constN-...)")
    return int(name[5])


def util_anchors(data_dir: Path, constellation: int) -> Anchors:
    from harness.flight.formats.anchors import load_anchors
    return load_anchors(data_dir / "util" / "anchors.csv", constellation)


def real_util_trials(data_dir: Path, group: UtilGroup) -> tuple[list[str], list[ErrorStats]]:
    from harness.flight.formats.util import load_util_csv
    files = sorted((data_dir / "util").glob(group.pattern))
    if not files:
        raise CalibrationError(f"no UTIL files {group.pattern} under {data_dir / 'util'}")
    stats = []
    for f in files:
        flight = load_util_csv(f, util_anchors(data_dir, _constellation_of(f)))
        u = flight.uwb
        assert u.true_value is not None
        stats.append(error_stats(u.value - u.true_value, u.anchor_a, u.anchor_b))
    return [f.name for f in files], stats


def sim_util_trials(data_dir: Path, group: UtilGroup, n_trials: int, duration_s: float,
                    config: SimConfig | None = None) -> tuple[list[str], list[ErrorStats]]:
    """Simulated campaign flights in the group's constellations (trial k flies constellation k mod n)."""
    from harness.flight.scenarios import scenario_flight
    consts = sorted({_constellation_of(f) for f in (data_dir / "util").glob(group.pattern)})
    if not consts:
        raise CalibrationError(f"no UTIL files {group.pattern} under {data_dir / 'util'}")
    cfg = config or sim_config(group.profile)
    names, stats = [], []
    for k in range(n_trials):
        c = consts[k % len(consts)]
        raw = util_anchors(data_dir, c)
        anchors = with_facing_orientations(raw, raw.positions.mean(axis=0))
        flight = scenario_flight("random", mode=group.mode, duration_s=duration_s, seed=1000 + k, noise="realistic",
                                 config=cfg, anchors=anchors, rate_hz=group.rate_hz, takeoff=True)
        u = flight.uwb
        assert u.true_value is not None
        stats.append(error_stats(u.value - u.true_value, u.anchor_a, u.anchor_b))
        names.append(f"sim const{c} random seed {1000 + k}")
    return names, stats
