"""The sections of the campaign report. A section is a function ``(ReportContext) -> Section | None``;
``DEFAULT_SECTIONS`` is the order of the page. Other parts of the project (e.g. closed-loop tracking)
add theirs by appending a function here or passing ``extra_sections`` to
``harness.report.build.build_report``; their ``Section.data`` lands in report.json under "sections"."""

from __future__ import annotations

import math
import platform
from typing import Any

from harness.kinds import KIND_KEYS
from harness.report import plots
from harness.report.context import ReportContext, SectionFn
from harness.report.data import TIME_BIN_S
from harness.report.html import FigureRef, Section, Table
from harness.report.recorded_phases import phase_table
from harness.report.summary import CONFIG_KEYS, DIVERGED_RMSE_M, PAPER


def _f(x: Any, digits: int = 3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def _pct(x: Any) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:+.1f} %"


def _ms(m: dict[str, Any], key: str) -> str:
    return f"{_f(m.get('rmse_' + key))} ± {_f(m.get('std_' + key))} (n={m.get('n_' + key, 0)})"


# ----------------------------------------------------------------------------------------- sections
def headline(ctx: ReportContext) -> Section | None:
    s = ctx.summary
    sec = Section("summary", "Accuracy: the paper's table")
    rows = []
    for mode in KIND_KEYS:
        m = s.get(mode)
        if not m:
            continue
        paper = PAPER[mode]
        rows.append([mode.upper(), _ms(m, "raw"), _ms(m, "outlier"), _ms(m, "outlier_nn"),
                     _pct(-m["reduction_pct"]), _pct(-m["reduction_paired_pct"]),
                     f"{paper['rmse_outlier_nn']:.2f} m, {-paper['reduction_pct']:+.1f} %"])
    if not rows:
        sec.paragraphs.append("Note: no simulated run completed; nothing to tabulate.")
        return sec
    seeds = sorted({x for mode in KIND_KEYS for x in (s.get(mode) or {}).get("seeds", [])})
    sec.paragraphs.append(
        "Position RMSE [m] of simulated flights, mean ± std over flights (seeds x trajectories), through the "
        f"firmware over the serial link. Seeds {seeds[0] if seeds else '-'}..{seeds[-1] if seeds else '-'} are "
        "disjoint from the training seeds (the network never saw these flights). Change = RMSE change of "
        "outlier rejection + NN versus outlier rejection alone: from the means, and the mean of the "
        "per-flight changes.")
    sec.tables.append(Table(["mode", "no rejection", "outlier rejection", "outlier rejection + NN",
                             "change (means)", "change (per flight)", "paper (+NN, change)"], rows,
                            "Simulated campaign"))
    traj_rows = []
    for mode in KIND_KEYS:
        for traj, m in ((s.get(mode) or {}).get("by_trajectory") or {}).items():
            traj_rows.append([f"{mode.upper()} {traj}", _ms(m, "raw"), _ms(m, "outlier"), _ms(m, "outlier_nn"),
                              _pct(-m["reduction_pct"])])
    if traj_rows:
        sec.tables.append(Table(["flight set", "no rejection", "outlier rejection", "outlier rejection + NN",
                                 "change (means)"], traj_rows, "Per trajectory"))
    _other_configs_table(sec, {mode: s[mode] for mode in KIND_KEYS if mode in s}, "simulated")
    sec.data = {mode: s[mode] for mode in KIND_KEYS if mode in s}
    return sec


def _other_configs_table(sec: Section, by_mode: dict[str, Any], what: str) -> None:
    """The configurations flown besides the paper's three (summary.other_configs), one row per mode and
    configuration; their filter consistency is in the consistency section."""
    rows = [[mode.upper(), cfg, f"{_f(m['rmse'])} ± {_f(m['std'])} (n={m['n']})",
             f"{_f(m['median'])}" + (f"; {m['diverged']} diverged" if m.get("diverged") else ""),
             _pct(m["change_vs_outlier_nn_pct"])]
            for mode, entry in by_mode.items() for cfg, m in (entry.get("other_configs") or {}).items()]
    if rows:
        sec.tables.append(Table(["mode", "configuration", "RMSE", "median", "change vs outlier rejection + NN"],
                                rows, f"Further configurations ({what})"))


def rmse_boxes(ctx: ReportContext) -> Section | None:
    figs = ctx.figure(plots.rmse_boxes(ctx.data), "rmse_boxes",
                      "Position RMSE per flight, per trajectory and configuration (paper Fig. 9).")
    return Section("rmse-boxes", "RMSE distribution (Fig. 9)", figures=figs) if figs else None


def error_time(ctx: ReportContext) -> Section | None:
    figs = ctx.figure(plots.error_over_time(ctx.data), "error_over_time",
                      f"Estimation error over time, mean over seeds (in {TIME_BIN_S} s bins) with a ±1 std band "
                      "(paper Fig. 7). Take-off and landing included.")
    return Section("error-time", "Error over time (Fig. 7)", figures=figs) if figs else None


def paths(ctx: ReportContext) -> Section | None:
    figs = ctx.figure(plots.paths_3d(ctx.data), "paths_3d",
                      "Estimated vs true 3-D paths of the lowest seed (paper Fig. 8, top).")
    return Section("paths", "Flight paths (Fig. 8)", figures=figs) if figs else None


def measurement_streams(ctx: ReportContext) -> Section | None:
    figs: list[FigureRef] = []
    for mode in KIND_KEYS:
        figs += ctx.figure(plots.measurement_stream(ctx.data, mode), f"stream_{mode}",
                           f"{mode.upper()}: measurement error, the bias the firmware's network subtracted "
                           "(RESULT.bias) and the measurements each gate rejected (paper Fig. 4).")
    return Section("stream", "Measurement stream of one flight (Fig. 4)", figures=figs) if figs else None


def recorded(ctx: ReportContext) -> Section | None:
    rec = ctx.summary.get("recorded")
    if not rec:
        return None
    sec = Section("recorded", "Recorded flights (held out from training)")
    sec.paragraphs.append(
        "Real UTIL and rcv_twr flights (the Crazyflie uSD logs have their own section) replayed through the "
        "firmware in UWB-only mode (constant-velocity model), on a firmware "
        "carrying the network trained on that kind of data: UTIL TDoA trials not used for training (trial 5 "
        "of constellations 1 and 2, constellation 3 with obstacles) and the held-out rcv_twr sequence. RMSE "
        f"against motion capture [m]. A run above {DIVERGED_RMSE_M:.0f} m has left the arena (diverged): the "
        "mean then says little, so the median is given too.")
    rows = [[mode.upper(), *[f"{_ms(m, k)}; median {_f(m.get('median_' + k))}"
                             + (f"; {m['diverged_' + k]} diverged" if m.get("diverged_" + k) else "")
                             for k in ("raw", "outlier", "outlier_nn")],
             _pct(-m["reduction_pct"]), _pct(-m["reduction_paired_pct"])]
            for mode, m in rec.items() if mode in KIND_KEYS]
    sec.tables.append(Table(["mode", "no rejection", "outlier rejection", "outlier rejection + NN",
                             "change (means)", "change (per flight)"], rows, "Over recorded flights"))
    frows = [[f["flight_id"], _f(f.get("rmse_raw")), _f(f.get("rmse_outlier")), _f(f.get("rmse_outlier_nn")),
              _pct(-100.0 * (f["rmse_outlier"] - f["rmse_outlier_nn"]) / f["rmse_outlier"])
              if f.get("rmse_outlier") and f.get("rmse_outlier_nn") is not None else "-"]
             for f in rec.get("flights", [])]
    extra = list(dict.fromkeys(c for f in rec.get("flights", []) for c in f.get("other_configs") or {}))
    for row, f in zip(frows, rec.get("flights", [])):
        row += [_f((f.get("other_configs") or {}).get(c)) for c in extra]
    sec.tables.append(Table(["flight", "no rejection", "outlier rejection", "outlier rejection + NN",
                             "change", *extra], frows, "Per flight"))
    phases = phase_table(rec.get("flights", []))
    if phases is not None:
        sec.tables.append(phases)
    _other_configs_table(sec, {m: v for m, v in rec.items() if m in KIND_KEYS}, "recorded")
    sec.figures += ctx.figure(plots.recorded_bars(ctx.data), "recorded_rmse", "RMSE per recorded flight.")
    sec.data = rec
    return sec


def latency(ctx: ReportContext) -> Section | None:
    lat = ctx.summary.get("latency") or {}
    budget = float(lat.get("budget_us", 5000.0))
    sec = Section("latency", "Latency")
    sec.paragraphs.append(
        "Device compute: the firmware's own cost of each measurement (RESULT.compute), over every run. End to "
        "end: host write of the measurement frame to receipt of its RESULT over the pty. It is taken from the "
        "real-time runs (frames sent at the data's own clock, as a sensor delivers them) when the campaign has "
        "them; with windowed pacing it would include queueing behind up to a window of measurements. "
        f"Deadline misses count samples above the {budget / 1e3:.0f} ms budget (one UWB slot at 200 Hz). "
        "Jitter is the p99 of |x - median|. Lost: measurements without a RESULT or ERROR.")
    rows = []
    for name in KIND_KEYS:
        k = lat.get(name)
        if not k:
            continue
        for label, st in ((f"compute [{k['compute_unit']}]", k["compute"]),
                          (f"end to end [us] ({k['end_to_end_pacing']})", k["end_to_end_us"])):
            rows.append([f"{name.upper()} {label}", str(st["n"]), _f(st["p50"], 1), _f(st["p90"], 1), _f(st["p99"], 1),
                         _f(st["p999"], 1), _f(st["max"], 1), _f(st["jitter_p99"], 1), str(st["deadline_misses"])])
    sec.tables.append(Table(["message type", "n", "p50", "p90", "p99", "p99.9", "max", "jitter p99",
                             "deadline misses"], rows, "Per message type"))
    counters = lat.get("device_counters", {})
    loss_rows = [[name.upper(), str(lat[name]["measurements"]), str(lat[name]["results"]), str(lat[name]["lost"]),
                  str(lat[name]["refused"])] for name in KIND_KEYS if name in lat]
    sec.tables.append(Table(["message type", "measurements sent", "RESULTs", "lost", "refused"], loss_rows,
                            "Frames"))
    sec.paragraphs.append("Device counters summed over runs: " + ", ".join(f"{k} {v}" for k, v in counters.items())
                          + f"; filter divergences (ERROR DIVERGED) {lat.get('divergences_total', 0)}.")
    sec.figures += ctx.figure(plots.latency_histograms(ctx.data, budget), "latency",
                              "Device compute time and end-to-end latency per message type (log axes).")
    sec.data = lat
    return sec


def failures(ctx: ReportContext) -> Section | None:
    runs = ctx.summary.get("runs") or {}
    sec = Section("runs", "Runs")
    sec.paragraphs.append(f"{runs.get('planned', 0)} planned, {runs.get('ok', 0)} complete, "
                          f"{runs.get('failed', 0)} failed, {runs.get('missing', 0)} not run.")
    for n in ctx.summary.get("notes", []):
        sec.paragraphs.append(f"Note: {n}")
    if runs.get("failed_runs"):
        sec.tables.append(Table(["run", "error"], [[f["run_id"], f"{f['error_type']}: "
                                                    f"{str(f['error']).splitlines()[0] if f['error'] else ''}"]
                                                   for f in runs["failed_runs"]], "Failed runs"))
    v = ctx.summary.get("verdict")
    if v:
        crit = ", ".join(f"{k} {x}" for k, x in (v.get("criteria") or {}).items())
        sec.paragraphs.append(
            f"Verdict: {'PASS' if v.get('passed') else 'FAIL'}: {v.get('judged_runs', 0)} runs of "
            f"{', '.join(v.get('judged_configs') or []) or 'no configuration'} judged (filter health"
            + (f"; {crit}" if crit else "") + f"), {v.get('not_judged', 0) } not judged"
            + (": failed " + "; ".join(v["failed_runs"]) if v.get("failed_runs") else "") + ".")
    if runs.get("missing_runs"):
        sec.paragraphs.append("Not run (interrupted?): " + ", ".join(runs["missing_runs"][:50])
                              + (" ..." if len(runs["missing_runs"]) > 50 else ""))
    sec.data = runs
    return sec


def provenance(ctx: ReportContext) -> Section | None:
    p = ctx.summary.get("provenance") or {}
    sec = Section("provenance", "Provenance")
    rows = [["firmware build id(s)", ", ".join(p.get("build_ids", []))],
            ["bias model hash(es)", "; ".join(f"{k}: {', '.join(v)}" for k, v in
                                              (p.get("model_hash_by_source") or {}).items())],
            ["protocol version(s)", ", ".join(str(v) for v in p.get("protocol_versions", []))],
            ["firmware binary", f"{p.get('firmware_path', '-')} (sha256 {p.get('firmware_sha256', '-')})"],
            ["git commit", f"{p.get('git_commit', '-')}{' (uncommitted changes)' if p.get('git_dirty') else ''}"],
            ["machine", f"{p.get('machine', '-')}: {p.get('platform', '-')}, {p.get('cpu_count', '-')} CPUs, "
                        f"Python {p.get('python', '-')}"],
            ["load average at start (1/5/15 min)", str(p.get("load_average_1_5_15", "-"))],
            ["campaign date (UTC)", str(p.get("date_utc", "-"))],
            ["report generated on", platform.node()],
            ["pacing", ", ".join(p.get("pacing") or [])],
            ["estimator overrides (--set)", ", ".join(p.get("estimator_settings") or []) or "none"]]
    sec.tables.append(Table(["what", "value"], rows))
    sec.data = p
    return sec


def bias_network(ctx: ReportContext) -> Section | None:
    """Paper Fig. 5 and the shipped networks' held-out figures (harness/report/bias_section.py)."""
    from harness.report.bias_section import bias_section
    return bias_section(ctx)


def radio_level(ctx: ReportContext) -> Section | None:
    """Radio-level flight sets (`campaign --radio`): both levels of each flight side by side."""
    rl = ctx.summary.get("radio_level")
    if not rl:
        return None
    sec = Section("radio_level", "LPS radio level: anchor packets through the tag's TDoA engine")
    sec.paragraphs.append(
        "The TDoA flights again at radio level (docs/radio.md): each flown as the anchor packets a Loco deck "
        "receives, the firmware's TDoA engine forming the measurements, and as the same flight's differences "
        "(same pairs, times and link errors), so the change is the engine's and the DW1000 tick's. These runs "
        "are their own flight sets: the accuracy and latency figures above do not include them. Drops: packets "
        "that formed no measurement, by reason; skew error: the engine's clock correction against the "
        "simulator's truth (recorded flights replay with ideal clocks).")

    def drops(d: dict[str, int]) -> str:
        return ", ".join(f"{k} {v}" for k, v in sorted(d.items())) or "none"

    sec.tables.append(Table(
        ["source", "protocol", "config", "flights", "RMSE measurement level", "RMSE radio level", "change (means)",
         "largest change", "packets", "measurements", "drops", "max skew error [ppm]"],
        [[g["source"], g["protocol"].upper(), g["config"], str(g["flights"]), _f(g["rmse_measurement"], 4),
          _f(g["rmse_radio"], 4), _pct(g["change_pct"]), f"{_f(g['max_abs_change_pct'], 1)} %", str(g["packets"]),
          str(g["measurements"]), drops(g["drops"]), _f(g["max_skew_error_ppm"], 4)] for g in rl["groups"]],
        "Per flight set (means over its flights)"))
    sec.tables.append(Table(
        ["flight", "config", "RMSE measurement level", "RMSE radio level", "change", "packets", "measurements",
         "drops", "max skew error [ppm]"],
        [[f["flight_id"], f["config"], _f(f["rmse_measurement"], 4), _f(f["rmse_radio"], 4), _pct(f["change_pct"]),
          str(f["packets"]), str(f["measurements"]), drops(f["drops"]), _f(f["max_skew_error_ppm"], 4)]
         for f in rl["flights"]], "Per flight"))
    if rl.get("unpaired"):
        sec.paragraphs.append("Without both levels (a run failed or is missing): " + "; ".join(rl["unpaired"]))
    sec.data = rl
    return sec


NEES_SKIP_S = 2.0        # the first seconds of each flight (initial convergence) are left out of the NEES
CONSISTENT_SHARE = 0.9   # "consistent": at least this share of epochs inside the 95 % bounds


def consistency(ctx: ReportContext) -> Section | None:
    """Filter consistency: position NEES averaged over the seeds of each simulated flight set, epoch by
    epoch (harness/report/consistency.py), with the two-sided 95 % chi-square bounds for 3 x runs dof."""
    from harness.report.consistency import monte_carlo_nees

    groups: dict[tuple[str, str, str], list[Any]] = {}
    for r in ctx.data.accuracy_runs:
        if r.source == "sim" and len(r.nees):
            groups.setdefault((r.mode, r.trajectory, r.config), []).append(r)
    rows, data = [], []
    for (mode, traj, cfg), runs in sorted(groups.items()):
        if len(runs) < 2:
            continue
        runs.sort(key=lambda r: (r.seed is None, r.seed))
        try:
            s = monte_carlo_nees([r.nees[r.nees_t_s >= NEES_SKIP_S] for r in runs])
        except ValueError:
            continue
        # by the epochs (the bounds hold per epoch; the mean of thousands of correlated epochs has none)
        below = 1.0 - s.inside - s.above
        verdict = ("consistent" if s.inside >= CONSISTENT_SHARE else
                   "under-confident" if below > s.above else "over-confident")
        rows.append([mode.upper(), traj, cfg, str(s.runs), str(s.epochs), _f(s.anees, 2), f"[{s.lo:.2f}, {s.hi:.2f}]",
                     f"{100 * s.inside:.0f} %", f"{100 * s.above:.0f} %", verdict])
        data.append({"mode": mode, "trajectory": traj, "config": cfg, "skip_s": NEES_SKIP_S,
                     "seeds": [r.seed for r in runs], **s.as_dict(), "verdict": verdict})
    if not rows:
        return None
    sec = Section("consistency", "Filter consistency (NEES over seeds)")
    sec.paragraphs.append(
        "Position NEES e^T P^-1 e from each RESULT's covariance diagonal, averaged over the seeds of a flight "
        f"set epoch by epoch (measurement index; the first {NEES_SKIP_S:.0f} s left out). A consistent filter "
        "has ANEES ~3 with ~95 % of epochs inside the bounds; the verdict says consistent when at least "
        f"{100 * CONSISTENT_SHARE:.0f} % are, else under-confident (more epochs below the lower bound: the "
        "filter reports more uncertainty than it has) or over-confident (more above the upper one).")
    sec.tables.append(Table(["mode", "trajectory", "config", "runs", "epochs", "ANEES", "95 % bounds",
                             "epochs inside", "epochs above", "verdict"], rows))
    sec.data = {"groups": data}
    return sec


def where_it_ran(ctx: ReportContext) -> Section | None:
    """Boards compared, or the Dask cluster and its retries (harness/report/boards_section.py)."""
    from harness.report.boards_section import boards, cluster
    return boards(ctx) or cluster(ctx)


def closed_loop(ctx: ReportContext) -> Section | None:
    """RUN_DIR/closed_loop.json written by `uwb-hil fly --out` (harness/report/closed_loop.py)."""
    from harness.report.closed_loop import closed_loop_section
    return closed_loop_section(ctx)


def crazyflie(ctx: ReportContext) -> Section | None:
    """The Crazyflie uSD flights: IMU vs UWB-only, the real-flight network (harness/report/usd_section.py)."""
    from harness.report.usd_section import usd_section
    return usd_section(ctx)


DEFAULT_SECTIONS: tuple[SectionFn, ...] = (headline, rmse_boxes, error_time, paths, measurement_streams, bias_network, recorded,
                                           crazyflie, radio_level, consistency, closed_loop, latency, failures,
                                           where_it_ran, provenance)

__all__ = ["CONFIG_KEYS", "DEFAULT_SECTIONS", "ReportContext", "SectionFn"]
