"""Closed-loop section of the campaign report: the take-off / tracking table and the paper's Fig. 8 curves
(RMS over the seeds of the tracking error e_t against flight time), from the JSON of `uwb-hil fly`.

    uwb-hil fly --out RUN_DIR/closed_loop.json      # then
    uwb-hil report RUN_DIR                          # the report gains the "Closed loop" section
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from harness.report.html import Section, Table

RESULT_NAME = "closed_loop.json"
COLORS = {"none": "#8c8c8c", "outlier": "#ff7f0e", "outlier+nn": "#1f77b4"}


def _f(x: Any, d: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}f}"


def tracking_figure(result: dict[str, Any]) -> Figure | None:
    """One panel per (mode, mission): e_t RMS over seeds against time, +-1 std band, per configuration."""
    cells = result.get("cells", [])
    panels = sorted({(c["mode"], c["mission"]) for c in cells})
    if not panels:
        return None
    fig = Figure(figsize=(5.0 * len(panels), 3.4))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (mode, mission) in zip(axes, panels):
        for c in cells:
            if (c["mode"], c["mission"]) != (mode, mission) or not c["series"]["t"]:
                continue
            t = np.asarray(c["series"]["t"], dtype=float)
            r = np.asarray(c["series"]["rmse"], dtype=float)
            s = np.asarray(c["series"]["std"], dtype=float)
            color = COLORS.get(c["config"], None)
            ax.plot(t, r, lw=1.2, color=color, label=f"{c['config']} ({c['flights']} seeds)")
            ax.fill_between(t, np.maximum(r - s, 0.0), r + s, color=color, alpha=0.2, lw=0)
        ax.set_title(f"{mode.upper()} {mission}")
        ax.set_xlabel("flight time [s]")
        ax.set_ylabel("tracking error e_t RMS [m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def section_from_result(result: dict[str, Any], fig_path: Path | None = None) -> Section:
    rows = []
    for c in result.get("cells", []):
        rows.append([c["mode"], c["mission"], c["config"], f"{c['takeoff_success']}/{c['flights']}",
                     f"{c['completed']}/{c['flights']}",
                     f"{_f(c['tracking_rmse_mean'])} ± {_f(c['tracking_rmse_std'])}",
                     f"{_f(c['estimation_rmse_mean'])} ± {_f(c['estimation_rmse_std'])}"])
    sec = Section("closed-loop", "Closed loop: tracking and take-off (Fig. 8)")
    sec.paragraphs.append(
        "The device's estimator and position controller fly a simulated Crazyflie on UWB alone "
        "(docs/closed-loop.md). Take-off succeeds when the vehicle reaches 0.5 m within 3 s without tilting "
        "beyond 30 deg or drifting 0.5 m; tracking RMSE of e_t = |p_true - p_commanded| over the trajectory "
        "(take-off and landing excluded), mean ± std over the completed flights.")
    sec.tables.append(Table(["mode", "mission", "config", "take-off", "completed", "tracking RMSE [m]",
                             "estimation RMSE [m]"], rows))
    sec.data = {"cells": [{k: v for k, v in c.items() if k not in ("per_flight", "series")}
                          for c in result.get("cells", [])]}
    return sec


def closed_loop_section(ctx: Any) -> Section | None:
    """Report section (harness.report.sections signature): RUN_DIR/closed_loop.json if present."""
    path = Path(ctx.fig_dir).parent / RESULT_NAME
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        sec = Section("closed-loop", "Closed loop: tracking and take-off (Fig. 8)")
        sec.paragraphs.append(f"{path}: unreadable ({exc})")
        return sec
    sec = section_from_result(result)
    sec.figures += ctx.figure(tracking_figure(result), "closed_loop_tracking",
                              "Tracking error e_t against flight time, RMS over the seeds with a ±1 std band "
                              "(paper Fig. 8, bottom). Take-off at 2 s, landing in the last 5 s.")
    return sec
