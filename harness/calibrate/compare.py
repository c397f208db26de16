"""calibrate(): the simulator next to the real recordings, every statistic, as one dict."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

from harness.calibrate.rcv_twr import rcv_twr_links, twr_dependence, twr_stats
from harness.calibrate.stats import CalibrationError, trial_summary
from harness.calibrate.util_tdoa import UTIL_GROUPS, UtilGroup, real_util_trials, sim_util_trials
from harness.flight.measurement_errors import sim_config


def calibrate(data_dir: Path, n_trials: int = 5, duration_s: float = 60.0, groups: Sequence[UtilGroup] = UTIL_GROUPS,
              twr: bool = True) -> dict[str, Any]:
    if not data_dir.is_dir():
        raise CalibrationError(f"real data directory {data_dir} not found (set UWB_HIL_DATA or use --data)")
    util = []
    for g in groups:
        real_files, real = real_util_trials(data_dir, g)
        sim_names, sim = sim_util_trials(data_dir, g, n_trials, duration_s)
        util.append({"group": g.name, "profile": g.profile, "mode": g.mode, "real_files": real_files,
                     "sim_flights": sim_names, "real": trial_summary(real), "sim": trial_summary(sim),
                     "real_trial_stats": [dict(t.row(), pair_means=t.pair_means) for t in real],
                     "sim_trial_stats": [dict(t.row(), pair_means=t.pair_means) for t in sim]})
    result: dict[str, Any] = {"data_dir": str(data_dir), "sim_trials": n_trials, "sim_duration_s": duration_s,
                              "util": util, "profiles": {p: asdict(sim_config(p)) for p in ("los", "nlos")}}
    if twr:
        links = rcv_twr_links(data_dir)
        result["twr"] = {"stats": twr_stats(links), "dependence": twr_dependence(links)}
        result["_links"] = links
    return result
