"""Command-line side of verdicts and the planar mode (options, printing, exit codes) for `uwb-hil run`
and `uwb-hil demo`. The logic lives in harness/report/verdict.py and harness/report/geometry.py (the planar
mode's in harness/flight/planar.py, used by harness/run/source.py); this module only parses and prints.

Exit codes (harness/errors.py, README "Reading a report"): 0 pass, 1 verdict failed, 2 usage or input error,
3 device or link failure.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, Callable, Collection

from harness import options
from harness.errors import EXIT_PASS, EXIT_VERDICT
from harness.report import jsonsafe
from harness.report.verdict import Criteria, CriteriaError, Verdict, evaluate, evaluate_all

_CRITERIA_OPTIONS = (
    ("max_rmse", "position RMSE [m] (3-D; over the observable axes when z is not observable)"),
    ("max_rmse_xy", "horizontal position RMSE [m]"),
    ("max_p99_compute_us", "p99 of the device's compute time per measurement [us; instructions on QEMU]"),
    ("max_p99_rtt_us", "p99 of the round trip [us] (windowed pacing includes queueing)"),
    ("max_lost", "measurements that got no answer"),
    ("max_deadline_misses", "compute over the 5 ms budget, plus round trips over it in lockstep/realtime pacing"),
)


def add_verdict_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("verdict", "pass criteria (exit 1 if one fails; the filter's health is always checked)")
    for name, text in _CRITERIA_OPTIONS:
        g.add_argument("--" + name.replace("_", "-"), type=float, default=None, metavar="X", help=text)
    g.add_argument("--vdop-threshold", type=float, default=None, metavar="X",
                   help="z counts as not observable when VDOP is above this for most of the flight (default 5)")
    g.add_argument("--allow-unobservable", action="store_true", default=None,
                   help="a flight whose position is not observable (no axis) is reported, not failed "
                        "(default: it fails)")
    g.add_argument("--criteria", metavar="FILE.toml",
                   help="criteria from a TOML file (same names with underscores, e.g. max_rmse = 0.3); "
                        "options given on the command line win")


def add_planar_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("planar mode")
    g.add_argument("--height", metavar="Z|truth",
                   help="the tag's height is known: fuse a height pseudo-measurement before every UWB measurement, "
                        "Z metres, or 'truth' = the recording's ground-truth height at each measurement")
    g.add_argument("--height-std", type=options.number(float, 0.0, 1000.0, lo_open=True, unit=" m"), default=0.05,
                   metavar="M",
                   help="standard deviation of the height pseudo-measurement [m] (default 0.05)")


def criteria_from(args: argparse.Namespace, applicable: Collection[str] | None = None, command: str = "") -> Criteria:
    """The criteria of a command: the --criteria file, overridden by the options (ValueError if invalid). With
    `applicable` (a command that judges fewer figures, e.g. fly), other criteria in the file are refused."""
    base = (Criteria.from_toml(Path(args.criteria), applicable, command) if getattr(args, "criteria", None)
            else Criteria())
    given = {name: getattr(args, name, None) for name, _ in _CRITERIA_OPTIONS}
    given["vdop_threshold"] = getattr(args, "vdop_threshold", None)
    given["allow_unobservable"] = getattr(args, "allow_unobservable", None)
    try:
        return base.overridden_by(given)
    except CriteriaError as exc:   # name the option the user typed
        text = str(exc)
        for name, value in given.items():
            if value is not None:
                text = text.replace(f"{name} must", f"--{name.replace('_', '-')} must")
        raise CriteriaError(text) from None


def finish(args: argparse.Namespace, payload: dict[str, Any], summaries: list[dict[str, Any]], criteria: Criteria,
           print_text: Callable[[], None]) -> int:
    """Judge the runs, put the verdict into the payload, print (JSON or text) and return the exit code."""
    verdict = evaluate(summaries[0], criteria) if len(summaries) == 1 else evaluate_all(summaries, criteria)
    payload["verdict"] = verdict.as_dict()
    if getattr(args, "json", False):
        print(jsonsafe.dumps(payload))
    else:
        print_text()
        print_verdict(verdict)
    if not verdict.passed:
        print(f"uwb-hil: verdict failed: {verdict.reason()}", file=sys.stderr)
        return EXIT_VERDICT
    return EXIT_PASS


def print_verdict(verdict: Verdict) -> None:
    notes = "".join(f"; {n}" for n in dict.fromkeys(verdict.notes()))
    print(f"verdict: {'PASS' if verdict.passed else 'FAIL'} ({len(verdict.checks)} checks"
          + (f"; failed: {verdict.reason()}" if not verdict.passed else notes) + ")")


def print_health(summary: dict[str, Any]) -> None:
    """Geometry and filter-health lines under print_run's."""
    geo, h = summary.get("geometry") or {}, summary.get("health") or {}
    axes = [a for a, ok in (("xy", geo.get("xy_observable", True)), ("z", geo.get("z_observable", True))) if not ok]
    print(f"  geometry: HDOP p50 {_g(geo.get('hdop_p50'))}, VDOP p50 {_g(geo.get('vdop_p50'))}"
          + (" (height pseudo-measurements fused)" if geo.get("height_fused") else "")
          + (f"; NOT OBSERVABLE: {', '.join(axes)} (DOP above {_g(geo.get('vdop_threshold'))}"
             + (f", or the anchors on one plane ({100 * geo['mirror_share']:.0f} % of epochs: a mirror image "
                f"across it along {geo['mirror_axis']})" if geo.get("mirror_axis") else "")
             + " for most of the flight)" if axes else ""))
    print(f"  filter health: {h.get('divergences', 0)} supervisor resets"
          + (f" ({h['divergence_reasons']})" if h.get("divergence_reasons") else "")
          + f", {h.get('non_finite', 0)} non-finite, {h.get('not_pd', 0)} not positive definite"
          + (f"; {h['gap_restarts']} restarts after measurement gaps (longest {_g(h.get('longest_gap_s'))} s, "
             "not divergences)" if h.get("gap_restarts") else ""))


def print_phases(summary: dict[str, Any]) -> None:
    """A line per phase (flight, ground) when the run has a ground phase, and the attitude error's lines
    (the whole run, then per phase)."""
    acc, att = summary.get("accuracy") or {}, summary.get("attitude") or {}
    phases = acc.get("phases") or {}
    above = _g(acc.get("flight_above"))
    for name, where, judged in (("flight", "above", "judged by the verdict"), ("ground", "below", "not judged")):
        if name in phases:
            p = phases[name]
            print(f"  {name} phase (truth {where} {above} m): n {p['n']} of {acc.get('n')}, RMSE {_m(p['rmse'])} m "
                  f"(xy {_m(p['rmse_xy'])}, z {_m(p['rmse_z'])}, z mean error {_m(p['z_mean_error'], '+.3f')}, "
                  f"max {_m(p['max_error'])}); {judged}")
    if att:
        print("  attitude error (firmware vs truth) " + _attitude_text(att))
        for name, a in (att.get("phases") or {}).items():
            print(f"    {name} phase: " + _attitude_text(a))


def _attitude_text(a: dict[str, Any]) -> str:
    axes = ", ".join(f"{k} {_m(a[f'{k}_mean_deg'], '+.2f')}/{_m(a[f'{k}_rms_deg'], '.2f')}"
                     for k in ("roll", "pitch", "yaw"))
    return (f"n {a['n']}: angle p50 {_m(a['angle_p50_deg'], '.2f')} deg, p95 {_m(a['angle_p95_deg'], '.2f')} deg; "
            f"mean/RMS [deg] {axes}")


def _m(x: Any, spec: str = ".3f") -> str:
    """A figure for a text line: '-' when missing or not finite."""
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def rtt_misses_text(rtt: dict[str, Any]) -> str:
    """Round trips over the budget: deadline misses in lockstep/realtime pacing, queueing in windowed."""
    if rtt.get("deadline_misses") is not None:
        return f"deadline misses (5 ms) {rtt['deadline_misses']}"
    return (f"over 5 ms incl. queueing {rtt.get('over_budget_queued')} (windowed pacing: not deadline misses; "
            "--pacing lockstep or realtime measures them)")


def _g(x: Any) -> str:
    return "-" if x is None else (f"{x:.2f}" if isinstance(x, float) else str(x))

