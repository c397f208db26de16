"""Report sections on where the campaign ran (campaign.json "executor"):

* "Boards" (`campaign --target/--port/--boards`): the boards compared one by one: identity (HELLO at the
  start), runs, RMSE per configuration over the board's accuracy runs (recomputed from the raw results, as
  every figure of the report), device compute time, and the boards taken out (their runs moved to the others,
  or, found dead by the check after the last flight, their runs standing);
* "Dask cluster" (`campaign --scheduler`): the scheduler, flights per worker and the retries (flights run
  again after their worker was lost).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from harness.report.context import ReportContext
from harness.report.html import Section, Table


def _board_of(ctx: ReportContext, run_id: str) -> str | None:
    summary = ctx.data.cdir.read_summary(run_id) or {}
    board = summary.get("board")
    return str(board["name"]) if isinstance(board, dict) and board.get("name") else None


def board_rows(ctx: ReportContext) -> dict[str, dict[str, Any]]:
    """Per board: its runs' RMSE per configuration (accuracy runs), compute percentiles, counts."""
    out: dict[str, dict[str, Any]] = {}
    for r in ctx.data.runs:
        name = _board_of(ctx, r.run_id)
        if name is None:
            continue
        b = out.setdefault(name, {"runs": 0, "rmse": {}, "compute": []})
        b["runs"] += 1
        if r.role == "accuracy" and np.isfinite(r.rmse):
            b["rmse"].setdefault(r.config, []).append(r.rmse)
        if r.compute_us.size:
            b["compute"].append(r.compute_us)
    for b in out.values():
        b["rmse"] = {c: {"mean": float(np.mean(v)), "n": len(v)} for c, v in sorted(b["rmse"].items())}
        comp = np.concatenate(b.pop("compute")) if b["compute"] else np.zeros(0)
        b["compute_p50"] = float(np.percentile(comp, 50)) if comp.size else None
        b["compute_p99"] = float(np.percentile(comp, 99)) if comp.size else None
    return out


def boards(ctx: ReportContext) -> Section | None:
    executor = ctx.data.manifest.get("executor") or {}
    if executor.get("kind") != "boards":
        return None
    rows = board_rows(ctx)
    info = {b["name"]: b for b in executor.get("boards", [])}
    out = {b["board"]: b for b in executor.get("taken_out", [])}
    configs = sorted({c for b in rows.values() for c in b["rmse"]})
    sec = Section("boards", "Boards")
    sec.paragraphs.append(f"{len(info)} boards; the flights dealt to whichever board was free. RMSE [m]: mean over "
                          "the board's accuracy runs (different flights per board); compute: device time per "
                          "measurement (us; instructions on QEMU).")
    table = []
    for name, b in info.items():
        r = rows.get(name, {"runs": 0, "rmse": {}, "compute_p50": None, "compute_p99": None})
        hello = b.get("hello") or {}
        status = _status(out.get(name))
        table.append([name, f"{b.get('target')} {b.get('port')}", f"{hello.get('build_id', '-')} / "
                      f"{hello.get('model_hash', '-')}", b.get("serial_number") or "-", str(r["runs"]),
                      *[_f(r["rmse"].get(c, {}).get("mean")) for c in configs],
                      f"{_f(r['compute_p50'], 1)} / {_f(r['compute_p99'], 1)}", status])
    sec.tables.append(Table(["board", "target, port", "build / model", "serial number", "runs",
                             *[f"RMSE {c}" for c in configs], "compute p50 / p99", "status"], table))
    sec.data = {"boards": rows, "taken_out": list(out.values())}
    return sec


def _status(out: dict[str, Any] | None) -> str:
    """A board's status: ok, taken out mid-campaign (its runs moved), or found dead after its last flight."""
    if out is None:
        return "ok"
    if out.get("after_last_flight"):
        return f"lost after its last flight: {out['reason']} (its runs stand)"
    return f"taken out: {out['reason']} ({out['moved_runs']} runs moved)"


def cluster(ctx: ReportContext) -> Section | None:
    executor = ctx.data.manifest.get("executor") or {}
    if executor.get("kind") != "dask":
        return None
    sec = Section("cluster", "Dask cluster")
    per_worker = executor.get("flights_per_worker") or {}
    retried = executor.get("retried_flights") or []
    sec.paragraphs.append(f"Scheduler {executor.get('scheduler')}, {executor.get('workers_at_start', '?')} workers at "
                          f"the start; {executor.get('retries', 0)} retries (flights run again after their worker was "
                          "lost)" + (": " + ", ".join(retried) if retried else "") + ".")
    sec.tables.append(Table(["worker", "flights"], [[w, str(n)] for w, n in sorted(per_worker.items())]))
    sec.data = {k: executor.get(k) for k in ("scheduler", "workers_at_start", "retries", "retried_flights",
                                             "flights_per_worker")}
    return sec


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"
