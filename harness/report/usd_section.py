"""The campaign report's section on the Crazyflie uSD flights (harness/campaign/recorded_usd.py): every shared
flight with the IMU and UWB-only, per configuration; the real-flight network's configurations on the flights
it never saw; the paper's Fig. 5 from real attitude (measured error and the network's bias against the
anchor's azimuth and elevation in the body frame) and the position error over time of the unseen flights.

Everything comes from the campaign directory (runs, DIR/models), never from the checkout."""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure

from harness.campaign.recorded_usd import CF_MODEL_KEY, LABEL_PREFIX, is_usd, log_name, replay_of, usd_role
from harness.report.data import CampaignData, RunMetrics

if TYPE_CHECKING:
    from harness.report.context import ReportContext
    from harness.report.html import Section, Table

#: the replays of a log, in table order, and their column labels (harness/campaign/recorded_usd.py replay_of)
REPLAYS = {"uwb": "UWB-only", "imu": "IMU", "tof": "IMU + ToF"}
ROLES = ("held-out", "shelf", "training")
#: the error-over-time axis is cut here: the ground phases leave it until the estimator's ground phase holds
ERROR_AXIS_M = 2.0


def usd_runs(data: CampaignData) -> list[RunMetrics]:
    return [r for r in data.accuracy_runs if r.source == "recorded" and is_usd(r.trajectory)]


def _phase_rmse(r: RunMetrics, phase: str) -> float:
    """The run's RMSE in `phase` ("flight": truth above 0.4 m, "ground"; report/phases.py), NaN without it."""
    v = ((r.phases or {}).get(phase) or {}).get("rmse")
    return float(v) if isinstance(v, (int, float)) else math.nan


def usd_summary(data: CampaignData) -> dict[str, Any]:
    """Per log: role, whole-flight RMSE [m] per (replay, configuration) (`rmse`) and the flight phase's
    (`rmse_flight`: truth above 0.4 m, report/phases.py; runs with a ground phase); per role: the means of
    each (`means`, `means_flight`); `attitude`: the firmware's attitude error in flight (median total angle
    [deg]) per (replay, configuration), where the runs carry it."""
    flights: dict[str, dict[str, Any]] = {}
    for r in usd_runs(data):
        row = flights.setdefault(log_name(r.trajectory), {"role": usd_role(r.trajectory), "rmse": {},
                                                           "rmse_flight": {}})
        key = f"{replay_of(r.trajectory)} {r.config}"
        row["rmse"][key] = r.rmse
        if math.isfinite(_phase_rmse(r, "flight")):
            row["rmse_flight"][key] = _phase_rmse(r, "flight")
        att = ((r.attitude or {}).get("phases") or {}).get("flight", r.attitude or {})
        if isinstance(att.get("angle_p50_deg"), (int, float)):
            row.setdefault("attitude", {})[key] = float(att["angle_p50_deg"])
    return {"flights": dict(sorted(flights.items(), key=lambda kv: log_order(kv[0]))),
            "means": _role_means(flights, "rmse"), "means_flight": _role_means(flights, "rmse_flight")}


def log_order(name: str) -> tuple[Any, ...]:
    """Sort key of a log name in natural order (0425-traj2 before 0425-traj13)."""
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name))


def columns(summary: dict[str, Any], what: str = "rmse") -> dict[tuple[str, str], str]:
    """Every (replay, configuration) the logs have a `what` for -> its column header: replays in REPLAYS' order,
    configurations in the order flown (the ToF replays' no-rejection runs and further configurations such as
    outlier+nn+std included: every run flown has its column)."""
    keys = list(dict.fromkeys(k for f in summary["flights"].values() for k in f.get(what) or {}))
    pairs = [(replay, cfg) for replay in REPLAYS for cfg in dict.fromkeys(k.split(" ", 1)[1] for k in keys)
             if f"{replay} {cfg}" in keys]
    return {(replay, cfg): REPLAYS[replay] + "".join(" + " + ("NN" if part == "nn" else part)
                                                       for part in cfg.split("+") if cfg != "none")
            for replay, cfg in pairs}


def _role_means(flights: dict[str, dict[str, Any]], what: str) -> dict[str, dict[str, float]]:
    """Per role: the mean over its logs of each (replay, configuration) of `what` (finite values only)."""
    means: dict[str, dict[str, float]] = {}
    for role in ROLES:
        rows = [f[what] for f in flights.values() if f["role"] == role]
        keys = sorted({k for row in rows for k in row})
        means[role] = {k: float(np.mean([row[k] for row in rows if k in row and math.isfinite(row[k])]))
                       for k in keys if any(k in row and math.isfinite(row[k]) for row in rows)}
    return means


def _cell(rmse: dict[str, float], replay: str, cfg: str, digits: int = 3) -> str:
    v = rmse.get(f"{replay} {cfg}")
    return f"{v:.{digits}f}" if isinstance(v, float) and math.isfinite(v) else "-"


def _change(rmse: dict[str, float], base: str = "imu outlier", new: str = "imu outlier+nn") -> str:
    a, b = rmse.get(base), rmse.get(new)
    return f"{100.0 * (b - a) / a:+.1f} %" if a and b is not None and math.isfinite(a * b) else "-"


def error_time_figure(data: CampaignData) -> Figure | None:
    """Position error over time of the flights the network never saw: IMU + outlier, IMU + outlier + NN and
    UWB-only + outlier, one panel per log."""
    runs = [r for r in usd_runs(data) if usd_role(r.trajectory) != "training" and r.err_t_s.size]
    logs = sorted({log_name(r.trajectory) for r in runs}, key=log_order)
    if not logs:
        return None
    fig = Figure(figsize=(11, 2.4 * len(logs)), layout="constrained")
    axes = fig.subplots(len(logs), 1, squeeze=False)[:, 0]
    style = {("imu", "outlier"): ("#ff7f0e", "IMU + outlier rejection"),
             ("imu", "outlier+nn"): ("#1f77b4", "IMU + outlier rejection + NN"),
             ("tof", "outlier+nn"): ("#2ca02c", "IMU + ToF + outlier rejection + NN"),
             ("uwb", "outlier"): ("#8c8c8c", "UWB-only + outlier rejection")}
    for ax, log in zip(axes, logs):
        for (replay, cfg), (color, label) in style.items():
            r = next((r for r in runs if log_name(r.trajectory) == log and replay_of(r.trajectory) == replay
                      and r.config == cfg), None)
            if r is not None:
                ax.plot(r.err_t_s, r.err_mean, color=color, lw=1.0,
                        label=f"{label} (RMSE {r.rmse:.3f} m, in flight {_phase_rmse(r, 'flight'):.3f} m)")
        ax.set_title(f"{log} ({usd_role(LABEL_PREFIX + log)})", fontsize=9)
        ax.set_ylim(0.0, ERROR_AXIS_M)
        ax.set_ylabel("|error| [m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time since the first measurement [s] (ground phases included)")
    return fig


def usd_section(ctx: "ReportContext") -> "Section | None":
    from harness.report.html import Section, Table
    summary = usd_summary(ctx.data)
    if not summary["flights"]:
        return None
    sec = Section("crazyflie", "Real Crazyflie flights (uSD logs): IMU vs UWB-only, and the real-flight network")
    sec.paragraphs.append(
        "Crazyflie flights logged on board (IMU, TDoA, motion-capture pose with attitude), replayed through the "
        "firmware with the IMU (the paper's system), with the IMU and the flow deck's ToF ranger where the log has "
        "its readings (`uwb-hil run`'s default there) and UWB-only. Position RMSE [m] against motion capture over the whole flight, ground "
        "phases included, and over the flight phase alone (truth above 0.4 m: what the verdict judges). The network (real-flight, pose layout) runs only with the IMU (it takes the firmware's own "
        "attitude) and only on flights it was not trained on: held-out = 0425 flights 3, 8, 13, 18 (line of "
        "sight), shelf = 0426 flights 3 and 5 (a wooden shelf in the arena, never trained on).")
    sec.tables += _rmse_tables(summary, "rmse", "means", "")
    if any(f["rmse_flight"] for f in summary["flights"].values()):
        sec.tables += _rmse_tables(summary, "rmse_flight", "means_flight", ", flight phase (truth above 0.4 m)")
    sec.tables += _attitude_table(summary)
    sec.figures += _fig5(ctx)
    sec.figures += ctx.figure(error_time_figure(ctx.data), "crazyflie_error_time",
                              f"Position error over time of the flights the network never saw (mean |error| in "
                              f"0.5 s bins, axis cut at {ERROR_AXIS_M:g} m; take-off and landing included).")
    sec.data = summary
    return sec


def _rmse_tables(summary: dict[str, Any], what: str, means: str, title: str) -> list["Table"]:
    """The per-flight and per-role tables of one RMSE (`what` per flight, `means` per role)."""
    from harness.report.html import Table

    def changes(rmse: dict[str, float]) -> list[str]:
        return [_change(rmse), _change(rmse, "tof outlier", "tof outlier+nn"), _change(rmse, "uwb outlier", "imu outlier")]
    cols = columns(summary, what)
    rows = [[log, f["role"], *[_cell(f[what], *k) for k in cols], *changes(f[what])]
            for log, f in summary["flights"].items()]
    headers = [*cols.values(), "NN vs outlier", "NN vs outlier (ToF)", "IMU vs UWB-only (outlier)"]
    mrows = [[role, str(sum(f["role"] == role and bool(f[what]) for f in summary["flights"].values())),
              *[_cell(summary[means][role], *k) for k in cols], *changes(summary[means][role])]
             for role in ROLES if summary[means].get(role)]
    return [Table(["log", "role", *headers], rows, "Per flight" + title),
            Table(["flights", "n", *headers], mrows, "Means" + title)]


def _attitude_table(summary: dict[str, Any]) -> list["Table"]:
    """The firmware's attitude error in flight per log (IMU replays), if the runs carry it."""
    from harness.report.html import Table
    cols = columns(summary, "attitude")
    rows = [[log, f["role"], *[_cell(f["attitude"], *k, digits=2) for k in cols]]
            for log, f in summary["flights"].items() if f.get("attitude")]
    return [Table(["log", "role", *cols.values()], rows,
                  "The firmware's attitude against the logged attitude in flight: median total angle [deg]")] if rows else []


def _fig5(ctx: "ReportContext") -> list[Any]:
    """Fig. 5 from real attitude: the campaign's real-flight network on its stored held-out flight."""
    from harness.biasnet.network import BiasModel
    from harness.biasnet.plots import bias_vs_azimuth
    from harness.campaign.models import model_path, read_index
    from harness.flight.native import load_flight
    from harness.report.html import FigureRef
    root = ctx.data.root
    index = read_index(root)
    path = model_path(root, index, (index.get("families") or {}).get(CF_MODEL_KEY)) if index else None
    if index is None or path is None or not index.get("fig5_cf_flight"):
        return []
    model = BiasModel.load(path)
    flight = load_flight(root / "models" / index["fig5_cf_flight"])
    png = bias_vs_azimuth(model, flight, ctx.fig_dir / "fig5_crazyflie.png", note="held out", elevation=True)
    return [FigureRef(png, f"{flight.name}, never trained on: measured TDoA error and the real-flight network's "
                           f"bias (model {model.hash_hex}) against the anchor's azimuth and elevation in the body "
                           "frame, from the logged attitude (paper Fig. 5).")]
