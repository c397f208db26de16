"""The campaign's numbers: the paper's table (RMSE per configuration, reduction of the bias network versus
outlier rejection alone), per trajectory, on recorded flights, and latency per message type."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from harness.campaign.recorded_usd import is_usd
from harness.campaign.store import CampaignDataError, CampaignDir, read_json
from harness.report.data import CampaignData, RunMetrics
from harness.report.metrics import DEFAULT_BUDGET_S, latency_summary
from harness.report.radio_level import radio_level_summary
from harness.report.recorded_phases import phase_figures
from harness.kinds import KINDS
from protocol.messages import CostUnit

#: Configuration -> JSON key suffix (rmse_raw, rmse_outlier, rmse_outlier_nn).
CONFIG_KEYS = {"none": "raw", "outlier": "outlier", "outlier+nn": "outlier_nn"}
#: The paper's figures (Zhao et al., Sec. V): RMSE with outlier rejection + network, and its reduction
#: versus outlier rejection alone.
PAPER = {"twr": {"rmse_outlier_nn": 0.19, "reduction_pct": 18.5},
         "tdoa": {"rmse_outlier_nn": 0.21, "reduction_pct": 48.0}}
#: A run whose RMSE exceeds this left the arena (the filter diverged); counted apart, never hidden.
DIVERGED_RMSE_M = 10.0


def _mean_std(values: list[float]) -> tuple[float, float, int]:
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return float("nan"), float("nan"), 0
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0, int(v.size)


def rmse_table(runs: list[RunMetrics]) -> dict[str, Any]:
    """rmse_<cfg> (mean over flights), std_<cfg>, n_<cfg>, and the network's reduction vs outlier rejection:
    reduction_pct from the means, reduction_paired_pct the mean of per-flight reductions."""
    out: dict[str, Any] = {}
    by_cfg: dict[str, dict[str, float]] = {}
    for cfg, key in CONFIG_KEYS.items():
        rs = [r for r in runs if r.config == cfg]
        mean, std, n = _mean_std([r.rmse for r in rs])
        out[f"rmse_{key}"], out[f"std_{key}"], out[f"n_{key}"] = mean, std, n
        finite = [r.rmse for r in rs if math.isfinite(r.rmse)]
        out[f"median_{key}"] = float(np.median(finite)) if finite else float("nan")
        out[f"diverged_{key}"] = int(sum(1 for x in finite if x > DIVERGED_RMSE_M))
        by_cfg[cfg] = {r.flight_id: r.rmse for r in rs}
    a, b = out["rmse_outlier"], out["rmse_outlier_nn"]
    out["reduction_pct"] = 100.0 * (a - b) / a if math.isfinite(a) and math.isfinite(b) and a > 0 else float("nan")
    paired = [100.0 * (by_cfg["outlier"][f] - v) / by_cfg["outlier"][f]
              for f, v in by_cfg["outlier+nn"].items()
              if f in by_cfg["outlier"] and by_cfg["outlier"][f] > 0 and math.isfinite(v)]
    out["reduction_paired_pct"], out["reduction_paired_std_pct"], out["n_paired"] = _mean_std(paired)
    return out


def other_configs(runs: list[RunMetrics]) -> dict[str, dict[str, Any]]:
    """The configurations flown besides the paper's three (e.g. outlier+nn+std, robust), in the order flown:
    RMSE mean/std/n/median/diverged over flights, and the change of the means against outlier+nn."""
    nn, _, _ = _mean_std([r.rmse for r in runs if r.config == "outlier+nn"])
    out: dict[str, dict[str, Any]] = {}
    for cfg in dict.fromkeys(r.config for r in runs if r.config not in CONFIG_KEYS):
        rs = [r.rmse for r in runs if r.config == cfg]
        mean, std, n = _mean_std(rs)
        finite = [x for x in rs if math.isfinite(x)]
        out[cfg] = {"rmse": mean, "std": std, "n": n, "median": float(np.median(finite)) if finite else float("nan"),
                    "diverged": int(sum(1 for x in finite if x > DIVERGED_RMSE_M)),
                    "change_vs_outlier_nn_pct": 100.0 * (mean - nn) / nn
                    if math.isfinite(mean) and math.isfinite(nn) and nn > 0 else float("nan")}
    return out


def accuracy_section(data: CampaignData) -> dict[str, Any]:
    out: dict[str, Any] = {}
    sim = [r for r in data.accuracy_runs if r.source == "sim"]
    for mode in ("twr", "tdoa"):
        runs = [r for r in sim if r.mode == mode]
        if not runs:
            continue
        entry = rmse_table(runs)
        entry["paper"] = PAPER[mode]
        entry["by_trajectory"] = {t: rmse_table([r for r in runs if r.trajectory == t])
                                  for t in sorted({r.trajectory for r in runs})}
        entry["seeds"] = sorted({int(r.seed) for r in runs if r.seed is not None})
        entry["other_configs"] = other_configs(runs)
        entry["divergences"] = {cfg: int(sum(r.divergences for r in runs if r.config == cfg))
                                for cfg in [*CONFIG_KEYS, *entry["other_configs"]]}
        out[mode] = entry
    rec = [r for r in data.accuracy_runs if r.source == "recorded" and not is_usd(r.trajectory)]  # usd_section.py
    if rec:
        recorded: dict[str, Any] = {}
        for mode in ("twr", "tdoa"):
            runs = [r for r in rec if r.mode == mode]
            if runs:
                recorded[mode] = rmse_table(runs) | {"other_configs": other_configs(runs)}
        flights = []
        for fid in sorted({r.flight_id for r in rec}):
            rs = [r for r in rec if r.flight_id == fid]
            row: dict[str, Any] = {"flight_id": fid, "mode": rs[0].mode, "trajectory": rs[0].trajectory}
            row.update({f"rmse_{CONFIG_KEYS[r.config]}": r.rmse for r in rs if r.config in CONFIG_KEYS})
            row["other_configs"] = {r.config: r.rmse for r in rs if r.config not in CONFIG_KEYS}
            row.update(phase_figures(rs))     # real logs: flight / ground phase, attitude error
            flights.append(row)
        recorded["flights"] = flights
        out["recorded"] = recorded
    return out


def latency_section(data: CampaignData, budget_s: float = DEFAULT_BUDGET_S) -> dict[str, Any]:
    """Per message type: device compute and end-to-end (host send -> RESULT received) percentiles, jitter,
    deadline misses against the budget; lost and refused measurements; device-side counters."""
    out: dict[str, Any] = {"budget_us": budget_s * 1e6}
    for kind, name in ((k.code, k.key) for k in KINDS.values()):
        runs = [r for r in data.measurement_runs if r.kind == kind]
        if not runs:
            continue
        units = {r.cost_unit for r in runs}
        compute = np.concatenate([r.compute_us for r in runs]).astype(np.float64)
        e2e_runs, e2e_pacing = data.e2e_runs(kind)
        rtt = np.concatenate([r.rtt_us for r in e2e_runs]).astype(np.float64)
        out[name] = {
            "runs": len(runs),
            "measurements": int(sum(r.measurements for r in runs)),
            "results": int(sum(r.results for r in runs)),
            "lost": int(sum(r.lost for r in runs)),
            "refused": int(sum(r.refused for r in runs)),
            "compute_unit": "us" if units == {CostUnit.NANOSECONDS} else "instructions",
            "compute": latency_summary(compute, budget_s * 1e6).as_dict() if units == {CostUnit.NANOSECONDS} else
            latency_summary(compute, budget_s * 168e6 / 2.0).as_dict(),
            "end_to_end_us": latency_summary(rtt, budget_s * 1e6).as_dict(),
            "end_to_end_pacing": e2e_pacing,
            "end_to_end_runs": [r.run_id for r in e2e_runs] if e2e_pacing == "realtime" else len(e2e_runs),
        }
    counters = ("crc_errors", "framing_errors", "seq_gaps", "dropped_meas", "non_finite", "unknown_anchors",
                "time_backwards")
    totals = {c: 0 for c in counters}
    for r in data.runs:
        for c in counters:
            totals[c] += int((r.device_stats or {}).get(c, 0))
    out["device_counters"] = totals
    out["lost_total"] = int(sum(r.lost for r in data.runs))
    out["divergences_total"] = int(sum(r.divergences for r in data.runs))
    return out


def provenance_section(data: CampaignData) -> dict[str, Any]:
    prov = dict(data.manifest.get("provenance") or {})
    prov["devices"] = data.devices
    prov["model_hashes"] = sorted({str(d.get("model_hash")) for d in data.devices})
    prov["build_ids"] = sorted({str(d.get("build_id")) for d in data.devices})
    prov["protocol_versions"] = sorted({int(d.get("proto_version", -1)) for d in data.devices})
    by_source: dict[str, set[str]] = {}
    for r in data.runs:
        by_source.setdefault(r.source, set()).add(r.model_hash)
    prov["model_hash_by_source"] = {k: sorted(v) for k, v in by_source.items()}
    prov["pacing"] = sorted({f"{r.role}: {r.pacing}" for r in data.runs})
    # estimator settings the runs overrode (`campaign --set`): the figures depend on them
    prov["estimator_settings"] = sorted({str(x) for r in data.manifest.get("runs", []) for x in r.get("settings", ())})
    return prov


def campaign_summary(data: CampaignData) -> dict[str, Any]:
    """The machine-readable summary (``uwb-hil report --json``)."""
    out = accuracy_section(data)
    out["latency"] = latency_section(data)
    out["runs"] = {"planned": len(data.manifest.get("runs", [])), "ok": len(data.runs),
                   "failed": len(data.failures), "missing": len(data.missing),
                   "failed_runs": [{"run_id": f.run_id, "error_type": f.error_type, "error": f.error}
                                   for f in data.failures],
                   "missing_runs": data.missing}
    radio = radio_level_summary(data)
    if radio is not None:
        out["radio_level"] = radio
    out["provenance"] = provenance_section(data)
    out["notes"] = list(data.manifest.get("notes") or [])
    verdict = stored_verdict(data)
    if verdict is not None:
        out["verdict"] = verdict
    return out


def stored_verdict(data: CampaignData) -> dict[str, Any] | None:
    """DIR/verdict.json of `uwb-hil campaign` (each judged run's checks), None if never judged. A damaged
    one is a CampaignDataError naming it: read as "never judged", a failed campaign's report passed."""
    path = CampaignDir(Path(data.root)).verdict
    v = read_json(path) if path.exists() else None
    if v is not None and not isinstance(v, dict):
        raise CampaignDataError(f"{path}: expected a JSON object (the campaign's verdict), got {type(v).__name__}")
    return v
