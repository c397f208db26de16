"""A small campaign through the emulator (2 seeds, short flights, 2 jobs), its report, resume and a failing run.

The report's numbers are checked against a recomputation made here from the raw JSONL results and the stored
truth (plain json + numpy.interp, not the report's own loader), and against the per-run summaries the workers
computed live from the in-memory flight.
"""

from __future__ import annotations

import gzip
import json
import os
import re
from dataclasses import replace
from pathlib import Path
from typing import IO, Any

import numpy as np
import pytest

from harness.campaign.plan import (FIRST_EVAL_SEED, RCV_TWR_HELD_OUT, RECORDED_MODELS, UTIL_HELD_OUT,
                                   CampaignOptions, PlanError, RunSpec, group_by_flight, held_out, plan_campaign)
from harness.campaign.runner import ExecOptions, group_stem, run_campaign
from harness.campaign.store import CampaignDataError, CampaignDir, load_results
from harness.report.build import build_report
from harness.report.html import Section
from harness.report.sections import ReportContext
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")

BOGUS = "/nonexistent/uwb-fw"
# Short flights without the take-off phase keep this under ~1 minute on a loaded 2-core machine.
OPTS = CampaignOptions(seeds=2, duration_s=6.0, takeoff=False, recorded=False, firmware=DEFAULT_FIRMWARE)


def _extra_section(ctx: ReportContext) -> Section:
    """Stands in for a later section (NEES, closed loop): proves the extension point reaches all outputs."""
    return Section("extra-test", "Extra test section", paragraphs=[f"{len(ctx.data.runs)} runs seen"],
                   data={"runs_seen": len(ctx.data.runs)})


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp("campaign")
    runs, _ = plan_campaign(OPTS)
    # One run points at a firmware that does not exist: it must fail alone, reported, the rest going on.
    k = next(i for i, r in enumerate(runs) if r.run_id == f"sim-tdoa-circle-z-s{FIRST_EVAL_SEED + 1}-none")
    runs[k] = replace(runs[k], firmware=BOGUS)
    logs: list[str] = []
    # keep_jsonl: the tests below recompute every figure from the raw JSON Lines (kept gzip-compressed)
    outcome = run_campaign(root, runs, ExecOptions(jobs=2, timeout_s=20.0, keep_jsonl=True), options=OPTS,
                           log=logs.append)
    files, summary = build_report(root, extra_sections=(_extra_section,))
    return {"root": root, "runs": runs, "outcome": outcome, "files": files, "summary": summary, "logs": logs,
            "bogus": runs[k].run_id}


# ------------------------------------------------------------------------------- independent recomputation
def _jsonl(root: Path, run_id: str) -> IO[str]:
    return gzip.open(root / "runs" / f"{run_id}.jsonl.gz", "rt", encoding="utf-8")


def _raw_rmse(root: Path, run_id: str, flight_id: str) -> float:
    truth = np.load(root / "flights" / f"{flight_id}.npz")
    t, p = [], []
    with _jsonl(root, run_id) as fh:
        for line in fh:
            rec = json.loads(line)
            if rec["type"] == "result" and rec["outcome"] == 1:
                t.append(rec["t_us"])
                p.append((rec["px"], rec["py"], rec["pz"]))
    tt = truth["truth_t_us"].astype(float)
    true = np.stack([np.interp(np.asarray(t, float), tt, truth["truth_pos"][:, i]) for i in range(3)], axis=1)
    return float(np.sqrt(np.mean(np.sum((np.asarray(p) - true) ** 2, axis=1))))


def test_campaign_runs_all_but_the_broken_run(campaign: dict[str, Any]) -> None:
    out = campaign["outcome"]
    assert out.total == len(campaign["runs"]) == 2 * 2 * 2 * 4 + 2   # + one real-time latency run per mode
    assert out.skipped == 0
    assert out.ok == out.total - 1
    assert [f["run_id"] for f in out.failed] == [campaign["bogus"]]
    assert "not found" in out.failed[0]["error"] and BOGUS in out.failed[0]["error"]
    s = CampaignDir(campaign["root"]).read_summary(campaign["bogus"])
    assert s is not None and s["status"] == "failed" and s["error_type"] == "InputFileNotFound"


def test_each_flight_and_firmware_group_has_its_own_worker_files(campaign: dict[str, Any]) -> None:
    # The broken run shares its flight with runs on the real firmware: two groups, one flight id. Named
    # by flight alone, their workers overwrote each other's job file (runs lost, JSONL written twice).
    groups = group_by_flight(campaign["runs"])
    logs = campaign["root"] / "logs"
    stems = {group_stem(g) for g in groups}
    assert len(stems) == len(groups) > len({g[0].flight.flight_id for g in groups})
    for g in groups:
        job = json.loads((logs / f"{group_stem(g)}.job.json").read_text())
        assert sorted(r["run_id"] for r in job["runs"]) == sorted(r.run_id for r in g)


def test_every_run_streamed_its_results_and_summary(campaign: dict[str, Any]) -> None:
    root = campaign["root"]
    for run in campaign["runs"]:
        if run.firmware == BOGUS:
            continue
        s = json.loads((root / "runs" / f"{run.run_id}.json").read_text())
        assert s["status"] == "ok" and s["fingerprint"] == run.fingerprint()
        assert not (root / "runs" / f"{run.run_id}.jsonl").exists()      # compressed once complete
        res = load_results(root / "runs" / f"{run.run_id}.jsonl.gz")
        n = s["flight"]["measurements"]
        assert len(res) == n > 1000 * (1 if run.flight.mode == "twr" else 2)
        assert np.array_equal(res.columns["index"], np.arange(n))
        assert int(np.count_nonzero(res.columns["outcome"] == 1)) == n       # nothing lost on a healthy run
        assert res.stats is not None and res.stats["results"] >= n
        assert s["flight"]["seed_disjoint_from_training"] is True and s["flight"]["seed"] >= FIRST_EVAL_SEED
        assert s["pacing"]["mode"] == run.pacing
        # The worker's live figure (in-memory flight) equals the recomputation from the files.
        assert s["summary"]["accuracy"]["rmse"] == pytest.approx(_raw_rmse(root, run.run_id, run.flight.flight_id),
                                                                 rel=1e-9)


def test_report_numbers_match_a_recomputation_from_raw_results(campaign: dict[str, Any]) -> None:
    root, summary = campaign["root"], campaign["summary"]
    on_disk = json.loads((root / "report.json").read_text())
    assert on_disk["twr"]["rmse_outlier"] == pytest.approx(summary["twr"]["rmse_outlier"])
    for mode in ("twr", "tdoa"):
        entry = on_disk[mode]
        per_cfg: dict[str, dict[str, float]] = {}
        for cfg, key in (("none", "raw"), ("outlier", "outlier"), ("outlier+nn", "outlier_nn")):
            runs = [r for r in campaign["runs"] if r.flight.mode == mode and r.config == cfg and r.role == "accuracy"
                    and r.firmware != BOGUS]
            vals = {r.flight.flight_id: _raw_rmse(root, r.run_id, r.flight.flight_id) for r in runs}
            per_cfg[cfg] = vals
            assert entry[f"n_{key}"] == len(vals) == (3 if (mode, cfg) == ("tdoa", "none") else 4)
            assert entry[f"rmse_{key}"] == pytest.approx(np.mean(list(vals.values())), rel=1e-9)
            assert entry[f"std_{key}"] == pytest.approx(np.std(list(vals.values()), ddof=1), rel=1e-9)
            assert 0.0 < entry[f"rmse_{key}"] < 1.0          # metres: a working filter on a 4 m circle
        a, b = entry["rmse_outlier"], entry["rmse_outlier_nn"]
        assert entry["reduction_pct"] == pytest.approx(100.0 * (a - b) / a, abs=1e-9)
        paired = [100 * (per_cfg["outlier"][f] - v) / per_cfg["outlier"][f] for f, v in per_cfg["outlier+nn"].items()]
        assert entry["reduction_paired_pct"] == pytest.approx(np.mean(paired), abs=1e-9)
        assert entry["paper"] == {"twr": {"rmse_outlier_nn": 0.19, "reduction_pct": 18.5},
                                  "tdoa": {"rmse_outlier_nn": 0.21, "reduction_pct": 48.0}}[mode]
        assert set(entry["by_trajectory"]) == {"circle", "circle-z"}
        assert entry["seeds"] == [FIRST_EVAL_SEED, FIRST_EVAL_SEED + 1]
        # the network with its own std (NN_STD) is flown by default and has its own row
        std_runs = [r for r in campaign["runs"] if r.flight.mode == mode and r.config == "outlier+nn+std"
                    and r.role == "accuracy"]
        vals = [_raw_rmse(root, r.run_id, r.flight.flight_id) for r in std_runs]
        other = entry["other_configs"]
        assert list(other) == ["outlier+nn+std"] and other["outlier+nn+std"]["n"] == len(vals) == 4
        assert other["outlier+nn+std"]["rmse"] == pytest.approx(np.mean(vals), rel=1e-9)
        assert other["outlier+nn+std"]["change_vs_outlier_nn_pct"] == pytest.approx(
            100.0 * (np.mean(vals) - b) / b, rel=1e-9)
        assert entry["divergences"]["outlier+nn+std"] == 0
    md = (root / "report.md").read_text()
    assert "Further configurations (simulated)" in md and "| TDOA | outlier+nn+std |" in md


def test_report_latency_matches_raw_results(campaign: dict[str, Any]) -> None:
    root, lat = campaign["root"], campaign["summary"]["latency"]
    for mode, kind in (("twr", 1), ("tdoa", 2)):
        compute, rtt = [], []
        for r in campaign["runs"]:
            if r.flight.mode != mode or r.firmware == BOGUS:
                continue
            for line in _jsonl(root, r.run_id):
                rec = json.loads(line)
                if rec["type"] == "result" and rec["outcome"] == 1:
                    assert rec["kind"] == kind
                    compute.append(rec["compute"] / 1e3)
                    if r.role == "latency":
                        rtt.append((rec["t_recv_ns"] - rec["t_send_ns"]) / 1e3)
        entry = lat[mode]
        assert entry["compute"]["n"] == len(compute)
        assert entry["compute"]["p99"] == pytest.approx(np.percentile(compute, 99), rel=1e-5)
        assert entry["end_to_end_pacing"] == "realtime"
        assert entry["end_to_end_us"]["n"] == len(rtt) > 0
        assert entry["end_to_end_us"]["p50"] == pytest.approx(np.percentile(rtt, 50), rel=1e-5)
        assert entry["end_to_end_us"]["deadline_misses"] == int(np.count_nonzero(np.asarray(rtt) > 5000.0))
        assert entry["lost"] == 0 and entry["refused"] == 0
        assert 0 < entry["compute"]["p50"] < 5000.0          # the firmware itself meets the 5 ms budget


def test_report_files_html_is_self_contained(campaign: dict[str, Any]) -> None:
    files = campaign["files"]
    for p in (files.html, files.markdown, files.json):
        assert p.exists() and p.stat().st_size > 0
    names = {p.name for p in files.figures}
    assert {"rmse_boxes.png", "error_over_time.png", "paths_3d.png", "stream_twr.png", "stream_tdoa.png",
            "latency.png"} <= names
    for p in files.figures:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    html = files.html.read_text()
    srcs = re.findall(r'<img[^>]*src="([^"]+)"', html)
    assert len(srcs) == len(files.figures)
    assert all(s.startswith("data:image/png;base64,") and len(s) > 5000 for s in srcs)   # embedded, not linked
    for needle in ("Provenance", "-18.5 %", "-48.0 %", campaign["bogus"], "Extra test section", "p99.9"):
        assert needle in html
    md = files.markdown.read_text()
    assert all(f"figures/{n}" in md for n in names)


def test_report_provenance_and_extension_sections(campaign: dict[str, Any]) -> None:
    s = campaign["summary"]
    prov = s["provenance"]
    assert re.fullmatch(r"[0-9a-f]{40}", prov["git_commit"])
    assert len(prov["model_hashes"]) == 1 and re.fullmatch(r"[0-9a-f]{16}", prov["model_hashes"][0])
    assert prov["model_hash_by_source"] == {"sim": prov["model_hashes"]}
    assert prov["build_ids"] and prov["protocol_versions"] and prov["machine"] and prov["date_utc"]
    assert s["runs"]["failed"] == 1 and s["runs"]["failed_runs"][0]["run_id"] == campaign["bogus"]
    assert s["sections"]["extra-test"] == {"runs_seen": campaign["outcome"].ok}


def _raw_nees(root: Path, run_id: str, flight_id: str, skip_s: float) -> np.ndarray:
    truth = np.load(root / "flights" / f"{flight_id}.npz")
    rows = []
    with _jsonl(root, run_id) as fh:
        for line in fh:
            rec = json.loads(line)
            if rec["type"] == "result" and rec["outcome"] == 1:
                rows.append([rec[k] for k in ("t_us", "px", "py", "pz", "var_x", "var_y", "var_z")])
    a = np.asarray(rows, dtype=np.float64)
    tt = truth["truth_t_us"].astype(float)
    true = np.stack([np.interp(a[:, 0], tt, truth["truth_pos"][:, i]) for i in range(3)], axis=1)
    nees = np.sum((a[:, 1:4] - true) ** 2 / a[:, 4:7], axis=1)
    return nees[(a[:, 0] - truth["uwb_t_us"][0]) * 1e-6 >= skip_s]


def test_report_nees_matches_a_recomputation_from_raw_results(campaign: dict[str, Any]) -> None:
    root = campaign["root"]
    groups = json.loads((root / "report.json").read_text())["sections"]["consistency"]["groups"]
    # every simulated flight set with at least two complete seeds (the bogus run leaves one)
    assert len(groups) == 2 * 2 * 4 - 1
    assert {(g["mode"], g["trajectory"]) for g in groups if g["config"] == "outlier+nn+std"} == {
        (m, t) for m in ("twr", "tdoa") for t in ("circle", "circle-z")}
    md = (root / "report.md").read_text()
    assert re.search(r"\| TWR \| circle \| outlier\+nn\+std \| 2 \|", md)
    for g in groups:
        runs = [r for r in campaign["runs"] if r.flight.mode == g["mode"] and r.flight.trajectory == g["trajectory"]
                and r.config == g["config"] and r.role == "accuracy"]
        assert len(runs) == g["runs"] == 2 and sorted(r.flight.seed for r in runs) == g["seeds"]
        per_run = [_raw_nees(root, r.run_id, r.flight.flight_id, g["skip_s"]) for r in runs]
        n = min(len(x) for x in per_run)
        avg = np.mean([x[:n] for x in per_run], axis=0)
        assert g["epochs"] == n and g["anees"] == pytest.approx(float(np.mean(avg)), rel=1e-6)
        assert 0.0 < g["lo"] < 3.0 < g["hi"]            # chi-square bounds of a mean over 2 runs x 3 dof
        assert g["verdict"] in ("consistent", "under-confident", "over-confident")
        inside = float(np.mean((avg >= g["lo"]) & (avg <= g["hi"])))
        assert g["inside"] == pytest.approx(inside) and g["above"] == pytest.approx(float(np.mean(avg > g["hi"])))
        assert (g["verdict"] == "consistent") == (inside >= 0.9)


def test_rerun_resumes_and_retries_only_what_is_not_done(campaign: dict[str, Any]) -> None:
    root, runs = campaign["root"], campaign["runs"]
    done = [r for r in runs if r.firmware != BOGUS]
    mtimes = {r.run_id: os.stat(root / "runs" / f"{r.run_id}.npy").st_mtime_ns for r in done}
    # Simulate an interruption in the middle of one run: its summary never got written.
    victim = next(r for r in done if r.run_id.endswith("-outlier") and r.flight.mode == "twr")
    (root / "runs" / f"{victim.run_id}.json").unlink()
    logs: list[str] = []
    out = run_campaign(root, runs, ExecOptions(jobs=2, timeout_s=20.0, keep_jsonl=True), options=OPTS,
                       log=logs.append)
    assert out.skipped == len(done) - 1
    assert out.ok == 1 and [f["run_id"] for f in out.failed] == [campaign["bogus"]]
    for r in done:
        changed = os.stat(root / "runs" / f"{r.run_id}.npy").st_mtime_ns != mtimes[r.run_id]
        assert changed == (r.run_id == victim.run_id), r.run_id
    assert CampaignDir(root).is_complete(victim.run_id, victim.fingerprint())


# ------------------------------------------------------------------------------------------ no device needed
def test_plan_covers_the_paper_grid_with_unseen_seeds() -> None:
    runs, notes = plan_campaign(CampaignOptions(recorded=False))
    acc = [r for r in runs if r.role == "accuracy"]
    assert len(acc) == 2 * 2 * 10 * 4 and len(runs) == len(acc) + 2
    assert {r.config for r in acc} == {"none", "outlier", "outlier+nn", "outlier+nn+std"}
    assert min(r.flight.seed for r in acc) == FIRST_EVAL_SEED and notes == []
    assert all(r.model is None for r in runs)            # simulated flights: the firmware's default model
    assert all(60.0 <= r.flight.duration_s <= 80.0 and r.flight.takeoff for r in acc)
    assert len({r.run_id for r in runs}) == len(runs)
    assert all(len(g) == 4 or (len(g) == 5 and g[-1].role == "latency") for g in group_by_flight(runs))
    assert RunSpec.from_dict(runs[-1].as_dict()) == runs[-1]
    assert replace(runs[0], config="outlier").fingerprint() != runs[0].fingerprint()
    with pytest.raises(PlanError, match="--modes"):
        plan_campaign(CampaignOptions(modes=("twr", "bogus")))
    with pytest.raises(PlanError, match="configuration"):
        plan_campaign(CampaignOptions(configs=("none", "nn-only")))


def test_recorded_flights_are_the_held_out_ones() -> None:
    data = shared_data_dir()
    if not (data / "util").is_dir():
        pytest.skip(f"shared data not found at {data}")
    runs, notes = plan_campaign(CampaignOptions(seeds=0, latency_runs=False, data_dir=data))
    # the Crazyflie uSD logs (IMU + UWB-only): tests/campaign/test_campaign_usd.py
    runs = [r for r in runs if not r.flight.trajectory.startswith("cf-")]
    paths = {r.flight.path for r in runs}
    assert {str(data / p) for p in UTIL_HELD_OUT} <= paths
    for p in paths:
        assert "trial5" in p or "const3" in p or "rcv_twr" in p, p     # never a training trial
        assert not re.search(r"const[12]-trial[1-4]-", p), p
    assert all(r.flight.uwb_only for r in runs)
    assert not any("not found: skipped" in n for n in notes), notes
    for family in ("util", "rcv_twr"):
        model_file = RECORDED_MODELS[family][1]
        fam = [r for r in runs if (r.flight.trajectory.startswith("util") == (family == "util"))]
        assert fam and all(r.model == (str(model_file) if model_file.is_file() else None) for r in fam)
        rels, _ = held_out(family)
        assert {str(data / p) for p in rels} == {r.flight.path for r in fam}


def test_bad_campaign_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(CampaignDataError, match="campaign.json: not found"):
        build_report(tmp_path)
    bad = tmp_path / "x.jsonl"
    bad.write_text('{"type": "header"}\n{"type": "result", "index": 0}\n')
    with pytest.raises(CampaignDataError, match=r"x\.jsonl:2: result field 'kind' missing"):
        load_results(bad)
    bad.write_text('{"type": "header"}\n{"type": "res')
    with pytest.raises(CampaignDataError, match=r"x\.jsonl:2: not JSON"):
        load_results(bad)


def test_a_rebuilt_firmware_invalidates_complete_runs(tmp_path: Path) -> None:
    cdir = CampaignDir(tmp_path)
    cdir.make()
    run = plan_campaign(CampaignOptions(seeds=1, modes=("twr",), trajectories=("circle",), recorded=False,
                                        latency_runs=False))[0][0]
    cdir.results_path(run.run_id).write_text('{"type": "header"}\n')
    cdir.summary_path(run.run_id).write_text(json.dumps({"status": "ok", "fingerprint": run.fingerprint(),
                                                         "firmware_sha256": "aaaa"}))
    assert cdir.is_complete(run.run_id, run.fingerprint(), "aaaa")
    assert not cdir.is_complete(run.run_id, run.fingerprint(), "bbbb")       # same path, other binary
    assert not cdir.is_complete(run.run_id, replace(run, config="outlier").fingerprint(), "aaaa")
    cdir.summary_path(run.run_id).write_text('{"status": "ok", "finger')  # torn: run again, no crash
    assert not cdir.is_complete(run.run_id, run.fingerprint(), "aaaa")


def _one_run() -> list[RunSpec]:
    return plan_campaign(CampaignOptions(seeds=1, modes=("twr",), trajectories=("circle",), configs=("none",),
                                         recorded=False, latency_runs=False))[0]


def test_a_crashed_worker_is_reported(tmp_path: Path) -> None:
    crash = tmp_path / "crash.sh"
    crash.write_text("#!/bin/sh\necho 'worker blew up' >&2\nexit 3\n")
    crash.chmod(0o755)
    runs = _one_run()
    out = run_campaign(tmp_path / "c", runs, ExecOptions(jobs=1, python=str(crash)), log=lambda s: None)
    assert out.ok == 0 and len(out.failed) == 1
    s = CampaignDir(tmp_path / "c").read_summary(runs[0].run_id)
    assert s is not None and s["status"] == "failed" and "exited with code 3" in s["error"]
    assert "worker blew up" in s["traceback"]


def test_a_hung_worker_is_stopped_and_reported(tmp_path: Path) -> None:
    hang = tmp_path / "hang.sh"
    hang.write_text("#!/bin/sh\nexec sleep 60\n")
    hang.chmod(0o755)
    runs = _one_run()
    out = run_campaign(tmp_path / "c", runs, ExecOptions(jobs=1, python=str(hang), group_timeout_s=1.0),
                       log=lambda s: None)
    assert out.ok == 0 and len(out.failed) == 1 and "timed out after 1 s" in out.failed[0]["error"]


def test_uwb_only_replays_leave_out_a_network_that_needs_the_attitude(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """rcv_twr.npz takes roll, pitch and yaw; the campaign replays rcv_twr UWB-only (no attitude), so its
    network configurations are left out with a note, as `uwb-hil run` refuses them, instead of a level
    attitude feeding the network a made-up input."""
    from harness.biasnet.network import BiasModel, init_network
    from harness.twin.features import LAYOUT_TWR_POS, LAYOUT_TWR_POSE
    data = shared_data_dir()
    if not (data / RCV_TWR_HELD_OUT[0]).is_dir():
        pytest.skip(f"shared data not found at {data}")
    import harness.campaign.plan as plan
    lo, hi = np.full(6, -1.0), np.full(6, 1.0)
    for layout, n_in, blind in ((LAYOUT_TWR_POSE, 6, True), (LAYOUT_TWR_POS, 3, False)):
        model = tmp_path / f"rcv_{layout}.npz"
        BiasModel(twr=init_network(layout, lo[:n_in], hi[:n_in], -0.5, 0.5, np.random.default_rng(1))).save(model)
        monkeypatch.setitem(plan.RECORDED_MODELS, "rcv_twr", ("rcv_twr", model))
        runs, notes = plan_campaign(CampaignOptions(seeds=0, modes=("twr",), latency_runs=False, data_dir=data))
        configs = sorted(r.config for r in runs)
        if blind:
            assert configs == ["none", "outlier"], configs
            assert any("takes roll, pitch and yaw" in n for n in notes), notes
        else:
            assert configs == ["none", "outlier", "outlier+nn", "outlier+nn+std"], configs
            assert not any("takes roll, pitch and yaw" in n for n in notes), notes
