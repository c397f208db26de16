"""A campaign split over machines: `uwb-hil campaign --shard K/N` runs a deterministic share of the plan,
`uwb-hil report DIR... --out M` merges the shard directories (refusing shards of different campaigns,
firmware or networks) and gives the report of the unsharded campaign. The directory is self-contained
(the networks it ran are copied into it) and keeps binary rows, not JSON Lines, once a run completes."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from harness.campaign.merge import MergeError, merge_shards
from harness.campaign.plan import CampaignOptions, PlanError, parse_shard, plan_campaign
from harness.campaign.shards import shard_runs
from harness.cli import main
from harness.paths import DEFAULT_FIRMWARE

pytestmark = [pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)"),
              pytest.mark.timeout(600)]

# A tiny campaign: three 11 s TWR flights x two configurations = 6 runs in 3 flights (one per shard).
TINY = ["--seeds", "3", "--modes", "twr", "--trajectories", "circle", "--configs", "none,outlier",
        "--duration", "11", "--no-recorded", "--no-latency-runs", "--jobs", "2"]


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    base = tmp_path_factory.mktemp("shards")
    assert main(["campaign", "--out", str(base / "all"), *TINY]) == 0
    for k in (1, 2, 3):
        assert main(["campaign", "--out", str(base / f"s{k}"), *TINY, "--shard", f"{k}/3", "--no-report"]) == 0
    assert main(["report", str(base / "s3"), str(base / "s1"), str(base / "s2"), "--out", str(base / "merged")]) == 0
    return {"base": base}


def _comparable(report: dict[str, Any]) -> dict[str, Any]:
    """The report minus what measures the machine rather than the firmware's estimates: timing percentiles
    (compute, round trip), when the report/campaign ran and the load average."""
    out = {k: v for k, v in report.items() if k not in ("latency", "report_generated_utc")}
    out["provenance"] = {k: v for k, v in report["provenance"].items()
                         if k not in ("date_utc", "load_average_1_5_15")}
    return out


def test_three_merged_shards_give_the_unsharded_report(campaigns: dict[str, Any]) -> None:
    base = campaigns["base"]
    one = json.loads((base / "all" / "report.json").read_text())
    merged = json.loads((base / "merged" / "report.json").read_text())
    assert one["runs"]["planned"] == one["runs"]["ok"] == 6 and one["runs"]["failed"] == 0
    assert 0.0 < one["twr"]["rmse_outlier"] < 0.2
    # the verdict judged the three "outlier" runs ("none", the baseline, is not judged by default) in every
    # shard; the merged report carries the shards' verdicts as one
    assert one["verdict"]["passed"] and one["verdict"]["judged_runs"] == 3 and one["verdict"]["not_judged"] == 3
    assert _comparable(merged) == _comparable(one)
    assert merged["latency"]["twr"]["compute"]["n"] == one["latency"]["twr"]["compute"]["n"]


def test_shards_partition_the_plan_deterministically(campaigns: dict[str, Any]) -> None:
    base = campaigns["base"]
    plan = [r["run_id"] for r in json.loads((base / "all" / "campaign.json").read_text())["runs"]]
    shards = [[r["run_id"] for r in json.loads((base / f"s{k}" / "campaign.json").read_text())["runs"]]
              for k in (1, 2, 3)]
    assert all(len(s) == 2 for s in shards)
    assert sorted(sum(shards, [])) == sorted(plan)
    runs, _ = plan_campaign(CampaignOptions(seeds=5, recorded=False))
    split = [shard_runs(runs, k, 4) for k in (1, 2, 3, 4)]
    assert sorted(r.run_id for s in split for r in s) == sorted(r.run_id for r in runs)
    assert [r.run_id for r in shard_runs(runs, 2, 4)] == [r.run_id for r in split[1]]
    for s in split:       # a flight's runs stay on one machine (built once)
        assert {r.flight.flight_id for r in s}.isdisjoint({r.flight.flight_id for t in split if t is not s
                                                            for r in t})
    assert parse_shard("2/4") == (2, 4)
    for bad in ("0/3", "4/3", "1", "a/b", "1/0"):
        with pytest.raises(PlanError, match="--shard"):
            parse_shard(bad)


def _shard_copy(src: Path, dst: Path, edit: Any) -> Path:
    shutil.copytree(src, dst)
    m = json.loads((dst / "campaign.json").read_text())
    edit(m)
    (dst / "campaign.json").write_text(json.dumps(m))
    return dst


@pytest.mark.parametrize("edit,match", [
    (lambda m: m["options"].__setitem__("duration_s", 12.0), "different options"),
    (lambda m: m["plan"].__setitem__("digest", "0" * 16), "another campaign spec"),
    (lambda m: m["provenance"].__setitem__("firmware_sha256", "f" * 16), "different firmware binary"),
    (lambda m: m["shard"].__setitem__("index", 1), "both shard 1/3"),
])
def test_merge_refuses_shards_of_different_campaigns(campaigns: dict[str, Any], tmp_path: Path, edit: Any,
                                                     match: str) -> None:
    base = campaigns["base"]
    other = _shard_copy(base / "s2", tmp_path / "s2", edit)
    with pytest.raises(MergeError, match=match):
        merge_shards([base / "s1", other, base / "s3"], tmp_path / "m")
    assert not (tmp_path / "m").exists()


def test_merge_refuses_other_networks_and_the_cli_exits_2(campaigns: dict[str, Any], tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    base = campaigns["base"]
    other = tmp_path / "s2"
    shutil.copytree(base / "s2", other)
    index = json.loads((other / "models" / "index.json").read_text())
    index["default"] = "0123456789abcdef"
    (other / "models" / "index.json").write_text(json.dumps(index))
    assert main(["report", str(base / "s1"), str(other), "--out", str(tmp_path / "m")]) == 2
    assert "ran different networks" in capsys.readouterr().err
    assert main(["report", str(base / "s1"), str(base / "s2")]) == 2
    assert "give --out" in capsys.readouterr().err


def test_campaign_directory_is_self_contained(campaigns: dict[str, Any], tmp_path: Path) -> None:
    base = campaigns["base"]
    root = base / "all"
    index = json.loads((root / "models" / "index.json").read_text())
    device_hashes = {json.loads(p.read_text())["device"]["model_hash"] for p in (root / "runs").glob("*.json")}
    assert device_hashes == {index["default"]}            # the network the firmware ran is the one copied
    assert (root / "models" / f"{index['default']}.npz").is_file()
    for key, h in index["families"].items():               # a models.json entry only with its network
        assert (root / "models" / index["files"][h]["file"]).is_file() and index["summary"][key]["hash"] == h
    assert set(index["summary"]) == set(index["families"])
    # Moved elsewhere, the directory gives the same report: nothing is read from the checkout.
    moved = tmp_path / "moved"
    shutil.copytree(root, moved)
    assert main(["report", str(moved)]) == 0
    a = json.loads((root / "report.json").read_text())
    b = json.loads((moved / "report.json").read_text())
    assert {k: v for k, v in a.items() if k != "report_generated_utc"} == \
        {k: v for k, v in b.items() if k != "report_generated_utc"}
    assert b["sections"]["bias-network"]["default_model"] == index["default"]


def test_complete_runs_keep_binary_rows_not_json_lines(campaigns: dict[str, Any], tmp_path: Path) -> None:
    runs = campaigns["base"] / "all" / "runs"
    assert sorted(p.suffix for p in runs.iterdir()) == [".json"] * 6 + [".npy"] * 6
    out = tmp_path / "kept"
    assert main(["campaign", "--out", str(out), *TINY[:-2], "--jobs", "1", "--seeds", "1", "--keep-jsonl",
                 "--no-report"]) == 0
    assert sorted(p.name.split(".", 1)[1] for p in (out / "runs").iterdir()) == ["json", "json", "jsonl.gz",
                                                                                  "jsonl.gz", "npy", "npy"]


def test_progress_shows_runs_done_of_total_and_an_eta(campaigns: dict[str, Any], tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "--out", str(tmp_path / "p"), *TINY, "--no-report"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("[")]
    assert [ln.split(" runs")[0] for ln in lines] == ["[2/6", "[4/6", "[6/6"]
    assert all(" elapsed, ETA " in ln for ln in lines) and lines[-1].split("ETA ")[1].startswith("0:00")


def test_models_json_entries_are_kept_only_with_their_network(tmp_path: Path) -> None:
    """The report once showed held-out figures of a models.json whose model file was absent: the snapshot
    keeps an entry only when the network it describes (same hash) is copied into the directory."""
    from harness.biasnet.export import DEFAULT_NPZ
    from harness.biasnet.network import BiasModel
    from harness.campaign.models import snapshot_models
    from harness.campaign.store import CampaignDir
    repo = tmp_path / "repo"
    models = repo / "firmware_sim" / "models"
    models.mkdir(parents=True)
    shutil.copyfile(DEFAULT_NPZ, models / "util_tdoa_pos.npz")
    h = BiasModel.load(DEFAULT_NPZ).hash_hex
    summary = {"util_tdoa_pos": {"file": "firmware_sim/models/util_tdoa_pos.npz", "hash": h, "heldout": {}},
               "rcv_twr": {"file": "firmware_sim/models/rcv_twr.npz", "hash": "0123456789abcdef"},   # absent
               "sim": {"file": "firmware_sim/models/util_tdoa_pos.npz", "hash": "fedcba9876543210"}}  # other net
    (models / "models.json").write_text(json.dumps(summary))
    cdir = CampaignDir(tmp_path / "c")
    cdir.make()
    index = snapshot_models(cdir, [None], tmp_path / "no-default.npz", models / "models.json", None)
    assert index["default"] is None and index["families"] == {"util_tdoa_pos": h}
    assert set(index["summary"]) == {"util_tdoa_pos"} and list(index["files"]) == [h]
    assert (cdir.root / "models" / f"{h}.npz").is_file() and index["fig5_rcv_flight"] is None
    assert any("rcv_twr" in n for n in index["notes"]) and any("sim" in n for n in index["notes"])
