"""Radio-level rows of a campaign (`uwb-hil campaign --radio tdoa2,tdoa3`): their own flight sets, both
levels of each flight, the radio section in the report; the measurement-level figures unchanged; shards
and merge as for any run."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from harness.campaign.plan import (ROLE_RADIO, ROLE_RADIO_MEAS, CampaignOptions, PlanError, UTIL_ANCHORS,
                                   UTIL_HELD_OUT, plan_campaign, plan_digest)
from harness.cli import main
from harness.report.data import load_campaign
from harness.report.summary import accuracy_section, latency_section
from harness.paths import DEFAULT_FIRMWARE, shared_data_dir

pytestmark = [pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)"),
              pytest.mark.timeout(900)]

# One 30 s simulated TDoA flight in one configuration, and the same flight at radio level (TDoA2, TDoA3),
# each of those flown as packets and as differences: 5 runs in 3 flights.
TINY = ["--seeds", "1", "--modes", "tdoa", "--trajectories", "circle", "--configs", "outlier", "--duration", "30",
        "--no-recorded", "--no-latency-runs", "--radio", "tdoa2,tdoa3", "--jobs", "2"]


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("radio_campaign")
    assert main(["campaign", "--out", str(base / "all"), *TINY]) == 0
    for k in (1, 2):
        assert main(["campaign", "--out", str(base / f"s{k}"), *TINY, "--shard", f"{k}/2", "--no-report"]) == 0
    assert main(["report", str(base / "s2"), str(base / "s1"), "--out", str(base / "merged")]) == 0
    return base


def test_radio_rows_carry_the_radio_section_and_agree_with_measurement_level(campaigns: Path) -> None:
    report = json.loads((campaigns / "all" / "report.json").read_text())
    assert report["runs"]["planned"] == report["runs"]["ok"] == 5
    rl = report["radio_level"]
    assert [(g["source"], g["protocol"], g["config"]) for g in rl["groups"]] == [("sim", "tdoa2", "outlier"),
                                                                              ("sim", "tdoa3", "outlier")]
    assert rl["unpaired"] == [] and len(rl["flights"]) == 2
    for row in rl["flights"]:
        # every packet answered: a measurement or a drop with its reason; the engine formed most of them
        assert row["measurements"] + sum(row["drops"].values()) == row["packets"] > 0
        assert row["measurements"] > 0.8 * row["packets"]
        assert set(row["drops"]) <= {"no_reference", "clock_unreliable", "expired"}
        assert row["max_skew_error_ppm"] < 0.05
        # the same flight as packets and as differences: position RMSE within 5 %
        assert 0.0 < row["rmse_measurement"] < 0.2
        assert abs(row["change_pct"]) < 5.0, row
        assert row["results_radio"] == row["measurements"]
    assert report["sections"].get("radio_level") is None       # once, under its own key
    md = (campaigns / "all" / "report.md").read_text()
    assert "LPS radio level" in md and "sim-tdoa-circle-s1000-radio-tdoa3" in md


def test_measurement_level_figures_do_not_see_the_radio_runs(campaigns: Path) -> None:
    data = load_campaign(campaigns / "all")
    radio = [r for r in data.runs if r.radio_level]
    assert sorted(r.role for r in radio) == [ROLE_RADIO, ROLE_RADIO, ROLE_RADIO_MEAS, ROLE_RADIO_MEAS]
    assert all((r.radio is not None) == (r.role == ROLE_RADIO) for r in radio)
    without = replace(data, runs=[r for r in data.runs if not r.radio_level])
    assert _same(accuracy_section(data), accuracy_section(without))   # NaN for configurations not flown
    assert _same(latency_section(data)["tdoa"], latency_section(without)["tdoa"])
    report = json.loads((campaigns / "all" / "report.json").read_text())
    assert report["tdoa"]["n_outlier"] == 1 and report["latency"]["tdoa"]["runs"] == 1


def _same(a: Any, b: Any) -> bool:
    return json.dumps(a, sort_keys=True, default=str) == json.dumps(b, sort_keys=True, default=str)


def test_radio_rows_shard_and_merge(campaigns: Path) -> None:
    one = json.loads((campaigns / "all" / "report.json").read_text())
    merged = json.loads((campaigns / "merged" / "report.json").read_text())
    assert merged["radio_level"] == one["radio_level"]
    assert merged["tdoa"] == one["tdoa"]


def _flight_ids(runs: list[Any], role: str) -> list[str]:
    return sorted({r.flight.flight_id for r in runs if r.role == role})


def test_plan_radio_sets_and_unchanged_fingerprints(tmp_path: Path) -> None:
    data = shared_data_dir()
    if not all((data / p).is_file() for p in (*UTIL_HELD_OUT, UTIL_ANCHORS)):
        pytest.skip("shared UTIL data not present")
    opts = CampaignOptions(seeds=1, trajectories=("circle",), data_dir=data, recorded_models=False)
    base, _ = plan_campaign(opts)
    runs, _ = plan_campaign(replace(opts, radio=("tdoa2", "tdoa3")))
    # the measurement-level runs are the same runs (fingerprints: resume of an existing campaign still works)
    assert {r.run_id: r.fingerprint() for r in runs if r.role not in (ROLE_RADIO, ROLE_RADIO_MEAS)} == \
        {r.run_id: r.fingerprint() for r in base}
    assert plan_digest(runs) != plan_digest(base)
    ids = _flight_ids(runs, ROLE_RADIO)
    assert ids == _flight_ids(runs, ROLE_RADIO_MEAS)
    # simulated TDoA flights at both protocols; held-out UTIL recordings at their own protocol; no TWR
    assert "sim-tdoa-circle-s1000-radio-tdoa2" in ids and "sim-tdoa-circle-s1000-radio-tdoa3" in ids
    assert "rec-tdoa-util-const1-trial5-tdoa3-radio-tdoa3" in ids
    assert "rec-tdoa-util-const1-trial5-tdoa2-radio-tdoa2" in ids
    assert not any("tdoa3-radio-tdoa2" in i or "tdoa2-radio-tdoa3" in i or "-twr-" in i for i in ids)
    assert len({r.run_id for r in runs}) == len(runs)


def test_radio_option_validation() -> None:
    with pytest.raises(PlanError, match="radio protocol"):
        plan_campaign(CampaignOptions(seeds=1, recorded=False, radio=("tdoa4",)))
    with pytest.raises(PlanError, match="needs tdoa"):
        plan_campaign(CampaignOptions(seeds=1, recorded=False, modes=("twr",), radio=("tdoa2",)))
