"""The recorded flights' phases in the campaign report: per flight and configuration, the RMSE of the flight
phase and of the ground phase (report/phases.py: truth below 0.4 m), and the firmware's attitude error in
flight (median / 95th percentile of the total angle), where the runs carry them (real Crazyflie logs)."""

from __future__ import annotations

import math
from typing import Any

from harness.report.data import RunMetrics
from harness.report.html import Table
from harness.report.phases import DEFAULT_FLIGHT_ABOVE_M

#: the attitude columns: the total angle error's median and 95th percentile [deg]
ATTITUDE_KEYS = ("angle_p50_deg", "angle_p95_deg")


def phase_figures(runs: list[RunMetrics]) -> dict[str, Any]:
    """For the runs of one recorded flight, keyed by configuration: `rmse_flight_phase`, `rmse_ground_phase`
    (runs with a ground phase) and `attitude_flight_phase` (its ATTITUDE_KEYS; the whole run's when the run
    has one phase). Keys absent when no run has them."""
    out: dict[str, Any] = {}
    phased = [r for r in runs if r.phases and "flight" in r.phases and "ground" in r.phases]
    if phased:
        out["rmse_flight_phase"] = {r.config: r.phases["flight"].get("rmse") for r in phased if r.phases}
        out["rmse_ground_phase"] = {r.config: r.phases["ground"].get("rmse") for r in phased if r.phases}
    att = {r.config: (r.attitude.get("phases") or {}).get("flight", r.attitude) for r in runs if r.attitude}
    if att:
        out["attitude_flight_phase"] = {cfg: {k: a.get(k) for k in ATTITUDE_KEYS} for cfg, a in att.items()}
    return out


def phase_table(flights: list[dict[str, Any]], above_m: float = DEFAULT_FLIGHT_ABOVE_M) -> Table | None:
    """Per recorded flight (rows of summary.accuracy_section's recorded "flights"): the RMSE in flight and on
    the ground per configuration, and the attitude error in flight of the last configuration that has one.
    None when no flight has phases or an attitude error."""
    rows = [f for f in flights if f.get("rmse_flight_phase") or f.get("attitude_flight_phase")]
    if not rows:
        return None
    configs = list(dict.fromkeys(c for f in rows for c in f.get("rmse_flight_phase") or {}))
    att_cfg = list(dict.fromkeys(c for f in rows for c in f.get("attitude_flight_phase") or {}))
    att_of = att_cfg[-1] if att_cfg else None
    headers = ["flight", *[f"{c}: in flight / ground [m]" for c in configs]]
    if att_of:
        headers.append(f"attitude error p50 / p95 [deg] in flight ({att_of})")
    table_rows = []
    for f in rows:
        fl, gr = f.get("rmse_flight_phase") or {}, f.get("rmse_ground_phase") or {}
        row = [str(f["flight_id"]), *[f"{_m(fl.get(c))} / {_m(gr.get(c))}" for c in configs]]
        if att_of:
            a = (f.get("attitude_flight_phase") or {}).get(att_of) or {}
            row.append(" / ".join(_m(a.get(k), 1) for k in ATTITUDE_KEYS))
        table_rows.append(row)
    return Table(headers, table_rows, f"Flight phase (truth above {above_m:g} m) and ground phase: RMSE against "
                                      "motion capture; the firmware's attitude against the logged attitude")


def _m(x: Any, digits: int = 3) -> str:
    return "-" if x is None or not isinstance(x, (int, float)) or not math.isfinite(x) else f"{x:.{digits}f}"
