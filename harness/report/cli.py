"""`uwb-hil report DIR`: the campaign report (HTML, Markdown, PNGs, JSON)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness.errors import EXIT_VERDICT, UsageError
from harness.kinds import KIND_KEYS
from harness.paths import output_path
from harness.report import jsonsafe


def add_parser(sub: Any) -> None:
    p = sub.add_parser("report", help="turn a campaign directory into report.html / report.md / report.json",
                       description="One directory: its report. Several (the shards of `uwb-hil campaign --shard "
                                   "K/N`): merged into --out (refused unless they are shards of one campaign with "
                                   "the same firmware and networks), then its report.")
    p.add_argument("dir", nargs="+", help="campaign directory (uwb-hil campaign --out DIR), or its shards")
    p.add_argument("--out", help="merged campaign directory (required with several directories)")
    p.add_argument("--json", action="store_true", help="print the summary JSON on stdout")
    p.set_defaults(func=cmd_report)


def write_report(root: Path, as_json: bool) -> dict[str, Any]:
    from harness.report.build import build_report
    files, summary = build_report(root)
    if as_json:
        print(jsonsafe.dumps(summary, indent=1))
    else:
        _print_headline(summary)
        print(f"report: {files.html} ({len(files.figures)} figures), {files.markdown}, {files.json}",
              file=sys.stderr)
    return summary


def _print_headline(summary: dict[str, Any]) -> None:
    def f(x: Any) -> str:
        return "-" if x is None else f"{x:.3f}"

    for mode in KIND_KEYS:
        m = summary.get(mode)
        if m:
            red = m.get("reduction_pct")
            print(f"{mode.upper():5s} RMSE [m]: none {f(m.get('rmse_raw'))}, outlier {f(m.get('rmse_outlier'))}, "
                  f"outlier+nn {f(m.get('rmse_outlier_nn'))}; NN vs outlier: "
                  f"{'-' if red is None else f'{-red:+.1f} %'} (paper {-m['paper']['reduction_pct']:+.1f} %)")
    for mode, m in (summary.get("recorded") or {}).items():
        if mode in KIND_KEYS:
            red = m.get("reduction_pct")
            print(f"recorded {mode.upper():5s}: none {f(m.get('rmse_raw'))}, outlier {f(m.get('rmse_outlier'))}, "
                  f"outlier+nn {f(m.get('rmse_outlier_nn'))}; NN vs outlier: "
                  f"{'-' if red is None else f'{-red:+.1f} %'}")
    for g in (summary.get("radio_level") or {}).get("groups", []):
        change = g.get("change_pct")
        print(f"radio {g['protocol'].upper()} {g['source']} {g['config']}: RMSE measurement level "
              f"{f(g.get('rmse_measurement'))}, radio level {f(g.get('rmse_radio'))} "
              f"({'-' if change is None else f'{change:+.1f} %'}; {g['flights']} flights)")
    runs = summary.get("runs") or {}
    if runs.get("failed") or runs.get("missing"):
        print(f"runs: {runs.get('failed')} failed, {runs.get('missing')} not run (see the report)")


def report_exit_code(summary: dict[str, Any]) -> int:
    """0 when every planned run completed and the verdict (if judged) passed; else 1 (EXIT_VERDICT) with one
    line on stderr: a report of a half-run or failed campaign is written, but does not pass as a good one."""
    runs = summary.get("runs") or {}
    verdict = summary.get("verdict") or {}
    reasons = [f"{runs[k]} run(s) {what}" for k, what in (("failed", "failed"), ("missing", "not run")) if runs.get(k)]
    if verdict.get("passed") is False:
        reasons.append(f"the verdict failed ({len(verdict.get('failed_runs') or [])} judged run(s))")
    if not reasons:
        return 0
    print(f"uwb-hil report: the campaign did not pass: {'; '.join(reasons)} (the report names them)", file=sys.stderr)
    return EXIT_VERDICT


def cmd_report(args: argparse.Namespace) -> int:
    dirs = [Path(d) for d in args.dir]
    if len(dirs) == 1 and not args.out:
        return report_exit_code(write_report(dirs[0], as_json=args.json))
    if not args.out:
        raise UsageError("several campaign directories are merged: give --out MERGED_DIR")
    from harness.campaign.merge import merge_shards
    output_path(args.out, "--out", directory=True)
    root = merge_shards(dirs, Path(args.out))
    print(f"merged {len(dirs)} shard directories into {root}", file=sys.stderr)
    return report_exit_code(write_report(root, as_json=args.json))
