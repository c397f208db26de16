"""The campaign report opens in a browser: report.html of a small campaign in headless Chromium
(browser_check.py beside this test; `make test` installs Debian's chromium through scripts/ensure_chromium.sh):
no console error, every figure decodes and is visible, the screenshot is not blank. Skipped, with the
reason, only where Chromium cannot start."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import pytest

from browser_check import check_report, chromium_problem
from harness.cli import main

WHY_NOT = chromium_problem()
pytestmark = pytest.mark.skipif(WHY_NOT is not None, reason=f"headless Chromium cannot start: {WHY_NOT}")


def test_the_campaign_report_renders_in_chromium(tmp_path: Path) -> None:
    out = tmp_path / "c"
    assert main(["campaign", "--out", str(out), "--seeds", "1", "--modes", "twr", "--trajectories", "circle",
                 "--configs", "none,outlier", "--duration", "11", "--no-recorded", "--no-latency-runs",
                 "--jobs", "1"]) == 0
    check = check_report(out / "report.html", tmp_path / "browser")
    assert check.problems() == []
    assert len(check.images) >= 3 and all(i["natural_w"] > 100 and i["visible"] for i in check.images)
    assert check.screenshot is not None and check.screenshot.stat().st_size > 10_000
    assert check.blank_share < 0.98


def _png() -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1, 2], [1, 3, 2])
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def test_the_check_sees_console_errors_broken_hidden_figures_and_blank_pages(tmp_path: Path) -> None:
    good = _png()
    page = tmp_path / "bad.html"
    page.write_text("<!DOCTYPE html><html><head><title>t</title></head><body><h1>Report</h1>"
                    f"<img alt=\"fine\" src=\"{good}\"><img alt=\"broken\" src=\"data:image/png;base64,AAAA\">"
                    f"<img alt=\"hidden\" style=\"display:none\" src=\"{good}\">"
                    "<script>console.error('figure 7 failed')</script></body></html>")
    problems = check_report(page, tmp_path / "b1").problems()
    assert any("console.error: figure 7 failed" in p for p in problems), problems
    assert any("figure 2 ('broken') does not decode" in p for p in problems), problems
    assert any("figure 3 ('hidden') is not visible" in p for p in problems), problems
    assert not any("'fine'" in p for p in problems)
    blank = tmp_path / "blank.html"
    blank.write_text("<!DOCTYPE html><html><head></head><body></body></html>")
    assert any("the screenshot is blank" in p for p in check_report(blank, tmp_path / "b2").problems())
