"""What a report section receives (the campaign's data, its summary, where figures go) and the section
signature. Its own module so that the sections in their own modules (report/bias_section.py,
report/closed_loop.py) depend on this type, not on the list of sections that calls them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from matplotlib.figure import Figure

from harness.report import plots
from harness.report.data import CampaignData
from harness.report.html import FigureRef, Section


@dataclass
class ReportContext:
    data: CampaignData
    summary: dict[str, Any]           # harness.report.summary.campaign_summary(data)
    fig_dir: Path

    def figure(self, fig: Figure | None, name: str, caption: str) -> list[FigureRef]:
        """Save a figure as <fig_dir>/<name>.png (nothing if fig is None)."""
        if fig is None:
            return []
        return [FigureRef(plots.save(fig, self.fig_dir / f"{name}.png"), caption)]


SectionFn = Callable[[ReportContext], "Section | None"]
