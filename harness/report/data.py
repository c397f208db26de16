"""Read a campaign directory into per-run metrics (from the raw JSONL results and the stored flights).

Everything the report shows is recomputed here from the raw files, not copied from the per-run summaries,
so the report and a test can check one against the other. Raw result arrays are dropped after each run's
metrics are computed (a full campaign holds millions of rows).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harness.campaign.store import (STATUS_OK, CampaignDataError, CampaignDir, StoredFlight, StoredResults,
                                    load_flight, load_run_results, read_json)
from harness.report.consistency import nees_of
from harness.stream.results_file import OUTCOME_ERROR, OUTCOME_LOST, OUTCOME_RESULT
from protocol.messages import CostUnit, Status

TIME_BIN_S = 0.5          # error-over-time curves are averaged in bins of this width


@dataclass
class RunMetrics:
    """One run, recomputed from its JSONL and its flight."""

    run_id: str
    flight_id: str
    source: str
    mode: str
    trajectory: str
    seed: int | None
    config: str
    measurements: int
    results: int
    lost: int
    refused: int
    rmse: float
    rmse_xy: float
    rmse_z: float
    max_error: float
    status_counts: dict[str, int]
    err_t_s: np.ndarray          # bin centres, seconds since the flight's first measurement
    err_mean: np.ndarray         # mean |p_est - p_true| per bin
    compute_us: np.ndarray       # float32, per RESULT (device cost; ns on the host build -> us)
    rtt_us: np.ndarray           # float32, per RESULT (host send -> host receive)
    kind: int
    device_stats: dict[str, Any] | None
    cost_unit: int = 0
    model_hash: str = ""
    divergences: int = 0         # the firmware's divergence guard re-initialised the filter (ERROR DIVERGED)
    pacing: str = "windowed"
    role: str = "accuracy"       # "latency": an extra real-time run, kept out of the accuracy figures
    # position NEES per RESULT (e^T diag(var)^-1 e from the RESULT's covariance diagonal; NaN if a variance
    # is not positive) and its time [s] since the flight's first measurement: the consistency section
    nees: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64))
    nees_t_s: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float64))
    radio: dict[str, Any] | None = None   # the run summary's radio section (role "radio": packets, drops, skew)
    # the run summary's accuracy per phase ({flight, ground}, report/phases.py; None: one phase) and the
    # firmware's attitude error against the truth (None: no attitude truth, or a UWB-only replay)
    phases: dict[str, Any] | None = None
    attitude: dict[str, Any] | None = None

    @property
    def radio_level(self) -> bool:
        """A run of a radio-level flight set (either level): kept out of the measurement-level figures."""
        return self.role in ("radio", "radio-meas")


@dataclass
class RunFailure:
    run_id: str
    flight_id: str
    config: str
    error_type: str
    error: str


@dataclass
class CampaignData:
    root: Path
    manifest: dict[str, Any]
    runs: list[RunMetrics]
    failures: list[RunFailure]
    missing: list[str]                       # planned runs without any summary (never ran / interrupted)
    devices: list[dict[str, Any]]            # distinct HELLO identities seen
    flights: dict[str, StoredFlight] = field(default_factory=dict)  # only those needed for plots
    _results: dict[str, StoredResults] = field(default_factory=dict)

    @property
    def cdir(self) -> CampaignDir:
        return CampaignDir(self.root)

    def results(self, run_id: str) -> StoredResults:
        """Rows of one run (the plots need a few runs' rows; those are kept after the first read)."""
        if run_id not in self._results:
            self._results[run_id] = load_run_results(self.cdir, run_id)
        return self._results[run_id]

    def flight(self, flight_id: str) -> StoredFlight:
        if flight_id not in self.flights:
            self.flights[flight_id] = load_flight(self.cdir.flight_path(flight_id))
        return self.flights[flight_id]

    @property
    def accuracy_runs(self) -> list[RunMetrics]:
        return [r for r in self.runs if r.role == "accuracy"]

    @property
    def measurement_runs(self) -> list[RunMetrics]:
        """Every run but the radio-level flight sets (their latency covers the TDoA engine too)."""
        return [r for r in self.runs if not r.radio_level]

    def e2e_runs(self, kind: int) -> tuple[list[RunMetrics], str]:
        """Runs whose end-to-end latency the report shows: the real-time ones if there are any."""
        runs = [r for r in self.measurement_runs if r.kind == kind]
        rt = [r for r in runs if r.pacing == "realtime"]
        return (rt, "realtime") if rt else (runs, ",".join(sorted({r.pacing for r in runs})))


_STATUS_NAMES = {status: status.name.lower() for status in Status}   # accepted, rejected_kinematic, ...


def position_error(res: StoredResults, flight: StoredFlight) -> tuple[np.ndarray, np.ndarray]:
    """(t_us, error vectors) of every measurement answered by a RESULT (same rule as harness.report.metrics)."""
    c = res.columns
    ok = c["outcome"] == OUTCOME_RESULT
    t = c["t_us"][ok]
    est = np.stack([c["px"][ok], c["py"][ok], c["pz"][ok]], axis=1)
    return t, est - flight.position_at(t)


def run_metrics(summary: dict[str, Any], res: StoredResults, flight: StoredFlight) -> RunMetrics:
    spec = summary["spec"]
    stored = summary.get("summary") or {}      # the run summary the worker wrote (summarize_run)
    f = spec["flight"]
    c = res.columns
    ok = c["outcome"] == OUTCOME_RESULT
    t, err = position_error(res, flight)
    norm = np.linalg.norm(err, axis=1)
    nan = float("nan")
    t0 = int(flight.uwb_t_us[0]) if len(flight.uwb_t_us) else 0
    if len(norm):
        rmse = float(np.sqrt(np.mean(norm ** 2)))
        rmse_xy = float(np.sqrt(np.mean(np.sum(err[:, :2] ** 2, axis=1))))
        rmse_z = float(np.sqrt(np.mean(err[:, 2] ** 2)))
        ts = (t - t0) * 1e-6
        bins = np.floor(ts / TIME_BIN_S).astype(np.int64)
        nb = int(bins.max()) + 1
        sums = np.bincount(bins, weights=norm, minlength=nb)
        counts = np.bincount(bins, minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            err_mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        err_t = (np.arange(nb) + 0.5) * TIME_BIN_S
    else:
        rmse = rmse_xy = rmse_z = nan
        err_mean = err_t = np.zeros(0)
    var = np.stack([c["var_x"][ok], c["var_y"][ok], c["var_z"][ok]], axis=1).astype(np.float64)
    status = c["status"][ok]
    cost_unit = int(summary.get("device", {}).get("cost_unit", CostUnit.NANOSECONDS))
    compute = c["compute"][ok]
    compute_us = (compute / 1e3 if cost_unit == CostUnit.NANOSECONDS else compute).astype(np.float32)
    rtt_us = ((c["t_recv_ns"][ok] - c["t_send_ns"][ok]) / 1e3).astype(np.float32)
    return RunMetrics(
        run_id=spec["run_id"], flight_id=spec["flight_id"], source=f["source"], mode=f["mode"],
        trajectory=f["trajectory"], seed=f.get("seed"), config=spec["config"], measurements=len(res),
        results=int(np.count_nonzero(ok)), lost=int(np.count_nonzero(c["outcome"] == OUTCOME_LOST)),
        refused=int(np.count_nonzero(c["outcome"] == OUTCOME_ERROR)), rmse=rmse, rmse_xy=rmse_xy, rmse_z=rmse_z,
        max_error=float(norm.max()) if len(norm) else nan,
        status_counts={name: int(np.count_nonzero(status == k)) for k, name in _STATUS_NAMES.items()},
        err_t_s=err_t, err_mean=err_mean, compute_us=compute_us, rtt_us=rtt_us, kind=int(flight.kind),
        device_stats=res.stats, cost_unit=cost_unit, model_hash=str(summary.get("device", {}).get("model_hash", "")),
        divergences=int(summary.get("divergences", 0)),
        pacing=str(spec.get("pacing", "windowed")),
        role=str(spec.get("role", "accuracy")),
        nees=nees_of(err, var), nees_t_s=(t - t0) * 1e-6,
        radio=stored.get("radio"), phases=(stored.get("accuracy") or {}).get("phases"),
        attitude=stored.get("attitude"))


def load_campaign(root: Path) -> CampaignData:
    """Every run of the campaign's manifest: metrics for complete runs, reasons for failed ones."""
    cdir = CampaignDir(Path(root))
    if not cdir.manifest.exists():
        raise CampaignDataError(f"{cdir.manifest}: not found; is {root} a campaign directory "
                                f"(written by `uwb-hil campaign --out {root}`)?")
    manifest = read_json(cdir.manifest)
    if not isinstance(manifest, dict) or not isinstance(manifest.get("runs"), list):
        raise CampaignDataError(f"{cdir.manifest}: field 'runs' missing or not a list")
    runs: list[RunMetrics] = []
    failures: list[RunFailure] = []
    missing: list[str] = []
    devices: dict[str, dict[str, Any]] = {}
    flights: dict[str, StoredFlight] = {}
    for planned in manifest["runs"]:
        run_id = planned["run_id"]
        summary = cdir.read_summary(run_id)
        if summary is None:
            missing.append(run_id)
            continue
        if summary.get("status") != STATUS_OK:
            failures.append(RunFailure(run_id=run_id, flight_id=planned["flight_id"], config=planned["config"],
                                       error_type=str(summary.get("error_type", "")),
                                       error=str(summary.get("error", ""))))
            continue
        fid = planned["flight_id"]
        if fid not in flights:
            flights[fid] = load_flight(cdir.flight_path(fid))
        res = load_run_results(cdir, run_id, stats=(summary.get("summary") or {}).get("device_stats"))
        if len(res) != int((summary.get("summary") or {}).get("measurements", len(res))):
            raise CampaignDataError(f"{cdir.results_path(run_id)}: {len(res)} rows, the run's summary says "
                                    f"{summary['summary']['measurements']} measurements")
        runs.append(run_metrics(summary, res, flights[fid]))
        dev = summary.get("device") or {}
        devices.setdefault(f"{dev.get('build_id')}/{dev.get('model_hash')}/{dev.get('proto_version')}", dev)
    # Keep only small flights in memory; plots reload what they need.
    return CampaignData(root=Path(root), manifest=manifest, runs=runs, failures=failures, missing=missing,
                        devices=list(devices.values()))
