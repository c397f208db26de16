"""`uwb-hil report DIR`: DIR/report.html (self-contained), DIR/report.md, DIR/report.json, DIR/figures/*.png."""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from harness.campaign.store import write_json_atomic
from harness.report.data import CampaignData, load_campaign
from harness.report.html import Section, render_html, render_markdown
from harness.report.sections import DEFAULT_SECTIONS, ReportContext, SectionFn
from harness.report.summary import campaign_summary

TITLE = "uwb-hil campaign report"


@dataclass(frozen=True)
class ReportFiles:
    html: Path
    markdown: Path
    json: Path
    figures: tuple[Path, ...]


def build_report(root: Path, sections: Sequence[SectionFn] = DEFAULT_SECTIONS,
                 extra_sections: Sequence[SectionFn] = ()) -> tuple[ReportFiles, dict[str, Any]]:
    root = Path(root)
    data: CampaignData = load_campaign(root)
    summary = campaign_summary(data)
    ctx = ReportContext(data=data, summary=summary, fig_dir=root / "figures")
    built: list[Section] = []
    for fn in (*sections, *extra_sections):
        sec = fn(ctx)
        if sec is not None:
            built.append(sec)
    summary["sections"] = {s.key: s.data for s in built if s.data and s.key != "summary" and s.key not in summary}
    summary["report_generated_utc"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    html_path, md_path, json_path = root / "report.html", root / "report.md", root / "report.json"
    html_path.write_text(render_html(TITLE, built), encoding="utf-8")
    md_path.write_text(render_markdown(TITLE, built, root), encoding="utf-8")
    summary = _finite_or_null(summary)
    write_json_atomic(json_path, summary)
    figures = tuple(f.path for s in built for f in s.figures)
    return ReportFiles(html=html_path, markdown=md_path, json=json_path, figures=figures), summary


def _finite_or_null(obj: Any) -> Any:
    """NaN/Inf are not JSON: a figure that does not exist (no runs) is written as null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_null(v) for v in obj]
    return obj
