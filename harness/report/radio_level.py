"""Radio-level rows of a campaign (`uwb-hil campaign --radio tdoa2,tdoa3`): each radio-level flight flown as
anchor packets through the tag's TDoA engine (role "radio") and as the same flight's differences (role
"radio-meas"), side by side. Kept apart from the measurement-level flight sets, whose figures they do not
change: the accuracy and latency sections never see these runs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from harness.report.data import CampaignData, RunMetrics


def _protocol(r: RunMetrics) -> str:
    """tdoa2 / tdoa3, from the flight id (…-radio-tdoa3) that both levels share."""
    return r.flight_id.rsplit("-radio-", 1)[-1]


def _pair_row(meas: RunMetrics, radio: RunMetrics) -> dict[str, Any]:
    sec = radio.radio or {}
    change = (100.0 * (radio.rmse - meas.rmse) / meas.rmse
              if math.isfinite(meas.rmse) and meas.rmse > 0 and math.isfinite(radio.rmse) else float("nan"))
    return {"flight_id": radio.flight_id, "source": radio.source, "protocol": _protocol(radio),
            "config": radio.config, "rmse_measurement": meas.rmse, "rmse_radio": radio.rmse,
            "change_pct": change, "results_measurement": meas.results, "results_radio": radio.results,
            "packets": sec.get("packets"), "measurements": sec.get("measurements"),
            "drops": {k: v for k, v in (sec.get("drops") or {}).items() if v},
            "max_skew_error_ppm": sec.get("max_skew_error_ppm")}


def _group(rows: list[dict[str, Any]]) -> dict[str, Any]:
    meas = np.array([r["rmse_measurement"] for r in rows], dtype=np.float64)
    radio = np.array([r["rmse_radio"] for r in rows], dtype=np.float64)
    change = np.array([r["change_pct"] for r in rows], dtype=np.float64)
    skew = [r["max_skew_error_ppm"] for r in rows if r["max_skew_error_ppm"] is not None]
    drops: dict[str, int] = {}
    for r in rows:
        for k, v in r["drops"].items():
            drops[k] = drops.get(k, 0) + int(v)
    mean_meas, mean_radio = float(np.nanmean(meas)), float(np.nanmean(radio))
    return {"flights": len(rows), "rmse_measurement": mean_meas, "rmse_radio": mean_radio,
            "change_pct": 100.0 * (mean_radio - mean_meas) / mean_meas if mean_meas > 0 else float("nan"),
            "max_abs_change_pct": float(np.nanmax(np.abs(change))) if np.isfinite(change).any() else float("nan"),
            "packets": int(sum(r["packets"] or 0 for r in rows)),
            "measurements": int(sum(r["measurements"] or 0 for r in rows)), "drops": drops,
            "max_skew_error_ppm": max(skew) if skew else None}


def radio_level_summary(data: CampaignData) -> dict[str, Any] | None:
    """Per radio-level flight and configuration both levels' RMSE, the change, packets, measurements formed,
    drops by reason and the engine's largest clock-skew error (against the simulator's truth); and the same
    per (source, protocol, configuration). None when the campaign flew no radio-level flight."""
    by_key: dict[tuple[str, str], dict[str, RunMetrics]] = {}
    for r in data.runs:
        if r.radio_level:
            by_key.setdefault((r.flight_id, r.config), {})[r.role] = r
    rows = [_pair_row(p["radio-meas"], p["radio"]) for _, p in sorted(by_key.items())
            if "radio" in p and "radio-meas" in p]
    unpaired = sorted(f"{fid} {cfg}" for (fid, cfg), p in by_key.items() if len(p) < 2)
    if not rows and not unpaired:
        return None
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["source"], row["protocol"], row["config"]), []).append(row)
    return {"flights": rows,
            "groups": [{"source": s, "protocol": p, "config": c, **_group(g)} for (s, p, c), g in sorted(groups.items())],
            "unpaired": unpaired}
