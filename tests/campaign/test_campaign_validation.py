"""Campaign options are refused before any worker starts (exit 2, the option named), not by every run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from harness.cli import main


@pytest.mark.parametrize("argv,match", [
    (["--duration", "10"], r"--duration 10: simulated flights need more than 10.5 s"),
    (["--duration", "nan"], r"--duration nan"),
    (["--trajectories", "circle,loop"], r"unknown trajectory 'loop'"),
    (["--jobs", "0"], r"--jobs must be >= 1"),
    (["--timeout", "-1"], r"--timeout must be in"),
    (["--firmware", "/nonexistent/uwb-fw"], r"firmware binary /nonexistent/uwb-fw not found"),
    (["--sim-model", "/nonexistent/m.npz"], r"--sim-model /nonexistent/m.npz: file not found"),
    (["--set", "proc_acc_xy=fast"], r"--set 'proc_acc_xy=fast': 'fast' is not a number"),
    (["--set", "stages=7"], r"--set 'stages=7': expected FIELD=VALUE"),
    (["--configs", "none"], r"the verdict judges no configuration of --configs none"),   # was PASS on 0 runs
])
def test_bad_campaign_options_are_refused_before_any_worker(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                           argv: list[str], match: str) -> None:
    out = tmp_path / "c"
    code = main(["campaign", "--out", str(out), "--seeds", "1", "--no-recorded", *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("uwb-hil: error: ") and len(err.strip().splitlines()) == 1
    assert re.search(match, err), err
    assert not out.exists()          # nothing planned, nothing started


def test_run_on_qemu_refuses_a_missing_firmware(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--target", "qemu", "--firmware", "/nonexistent.elf", "--duration", "2"])
    err = capsys.readouterr().err
    assert code == 2
    assert "uwb-hil: error: firmware ELF /nonexistent.elf not found" in err


def test_campaign_set_reaches_every_run_and_its_fingerprint(tmp_path: Path) -> None:
    import json
    from dataclasses import replace
    from harness.campaign.plan import CampaignOptions, RunSpec, plan_campaign
    base = CampaignOptions(seeds=1, modes=("tdoa",), trajectories=("circle",), configs=("outlier",), recorded=False,
                           latency_runs=False, duration_s=12.0)
    plain, _ = plan_campaign(base)
    tuned, _ = plan_campaign(replace(base, settings=("proc_acc_xy=0.05",)))
    assert "settings" not in plain[0].as_dict()          # campaigns without --set keep their fingerprints
    assert tuned[0].settings == ("proc_acc_xy=0.05",) and tuned[0].fingerprint() != plain[0].fingerprint()
    assert RunSpec.from_dict(tuned[0].as_dict()) == tuned[0]
    out = tmp_path / "c"
    assert main(["campaign", "--out", str(out), "--seeds", "1", "--duration", "12", "--modes", "tdoa",
                 "--trajectories", "circle", "--configs", "outlier", "--no-recorded", "--no-latency-runs",
                 "--no-report", "--set", "proc_acc_xy=0.05", "--set", "std_tdoa=0.2"]) == 0
    summary = json.loads(next((out / "runs").glob("*.json")).read_text())
    assert summary["estimator_config"]["proc_acc_xy"] == pytest.approx(0.05)
    assert summary["estimator_config"]["std_tdoa"] == pytest.approx(0.2)


def test_the_report_names_the_estimator_overrides(tmp_path: Path) -> None:
    """A campaign flown with `--set` says so in its provenance (summary JSON and the report's table)."""
    from types import SimpleNamespace

    from harness.report.data import CampaignData
    from harness.report.sections import provenance
    from harness.report.summary import provenance_section
    runs = [{"run_id": "a", "settings": ["proc_acc_xy=0.05", "proc_acc_z=0.1"]}, {"run_id": "b"}]
    prov = provenance_section(CampaignData(root=tmp_path, manifest={"runs": runs}, runs=[], failures=[], missing=[],
                                           devices=[]))
    assert prov["estimator_settings"] == ["proc_acc_xy=0.05", "proc_acc_z=0.1"]
    sec = provenance(SimpleNamespace(summary={"provenance": prov}))  # type: ignore[arg-type]
    assert sec is not None and ["estimator overrides (--set)", "proc_acc_xy=0.05, proc_acc_z=0.1"] in sec.tables[0].rows
    plain = provenance_section(CampaignData(root=tmp_path, manifest={"runs": runs[1:]}, runs=[], failures=[],
                                            missing=[], devices=[]))
    assert plain["estimator_settings"] == []


@pytest.mark.parametrize("argv,match", [
    (["--max-rmse", "-1"], r"--max-rmse must be a finite number >= 0"),
    (["--criteria", "/nonexistent/c.toml"], r"criteria file not found"),
    (["--judge", "outlier,robust+nn"], r"--judge: robust\+nn not among the configurations flown"),
])
def test_bad_campaign_criteria_are_refused_before_any_run(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          argv: list[str], match: str) -> None:
    out = tmp_path / "c"
    code = main(["campaign", "--out", str(out), "--seeds", "1", "--no-recorded", "--configs", "none,outlier", *argv])
    err = capsys.readouterr().err
    assert code == 2 and re.search(match, err), err
    assert not out.exists()


def test_campaign_verdict_judges_each_run_and_names_the_failing_one(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    import json
    out = tmp_path / "c"
    tiny = ["campaign", "--out", str(out), "--seeds", "1", "--duration", "11", "--modes", "tdoa", "--trajectories",
            "circle", "--configs", "none,outlier", "--no-recorded", "--no-latency-runs", "--jobs", "1"]
    assert main([*tiny, "--max-rmse", "5"]) == 0
    v = json.loads((out / "report.json").read_text())["verdict"]
    # "none" (the no-rejection baseline) is not judged by default; the outlier run is, health included
    assert v["passed"] and v["judged_configs"] == ["outlier"] and v["judged_runs"] == 1 and v["not_judged"] == 1
    names = [c["name"] for c in v["runs"][0]["checks"]]
    assert {"diverged", "non_finite_estimates", "rmse"} <= set(names)
    rmse = next(c for c in v["runs"][0]["checks"] if c["name"] == "rmse")
    assert 0 < rmse["value"] <= 5 and rmse["threshold"] == 5
    assert "Verdict: PASS" in (out / "report.md").read_text()
    assert main(["report", str(out)]) == 0                 # `report` exits as the campaign it reports
    capsys.readouterr()
    # same command again: every run resumes, and its stored summary is judged under the new criterion
    assert main([*tiny, "--max-rmse", "0.001", "--judge", "none,outlier"]) == 1
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if x.startswith("uwb-hil: verdict failed"))
    assert "2 of 2 judged runs failed" in line and "tdoa-circle-s1000 outlier (accuracy): rmse" in line, line
    assert "> 0.001" in line
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"]["passed"] is False and len(report["verdict"]["failed_runs"]) == 2
    assert "Verdict: FAIL" in (out / "report.md").read_text()
    capsys.readouterr()
    assert main(["report", str(out)]) == 1
    assert "the campaign did not pass: the verdict failed (2 judged run(s))" in capsys.readouterr().err
    for f in (out / "runs").glob("*outlier*"):            # a half-copied campaign: a run is missing
        f.unlink()
    assert main(["report", str(out)]) == 1
    assert "1 run(s) not run" in capsys.readouterr().err
    (out / "verdict.json").write_text("[]")                 # damaged: said, not read as "never judged" (PASS)
    assert main(["report", str(out)]) == 2
    assert "verdict.json: expected a JSON object" in capsys.readouterr().err


def test_a_campaign_with_no_runs_fails(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--seeds 0` without recorded flights planned 0 runs and printed "verdict: PASS" (issue 27)."""
    out = tmp_path / "c"
    assert main(["campaign", "--out", str(out), "--seeds", "0", "--no-recorded"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: no runs planned (--seeds 0") and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_recorded_data_asked_for_but_absent_is_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    out, nodata = tmp_path / "c", tmp_path / "no-data"
    monkeypatch.delenv("UWB_HIL_NO_RECORDED", raising=False)
    assert main(["campaign", "--out", str(out), "--seeds", "1", "--data-dir", str(nodata)]) == 2
    err = capsys.readouterr().err
    assert f"recorded flights asked for but the data folder {nodata} does not exist" in err
    assert "--no-recorded (or UWB_HIL_NO_RECORDED=1)" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    # the stated environment variable makes --no-recorded the default: the plan goes on without them
    from argparse import Namespace
    from harness.campaign.cli import _recorded
    monkeypatch.setenv("UWB_HIL_NO_RECORDED", "1")
    assert _recorded(Namespace(recorded=None)) is False and _recorded(Namespace(recorded=True)) is True


def test_a_cut_or_flipped_stored_flight_is_a_named_data_error(tmp_path: Path) -> None:
    """`uwb-hil report` on a campaign whose flights/*.npz was cut or damaged: CampaignDataError (exit 2), never
    zipfile's BadZipFile (exit 4)."""
    import numpy as np
    from harness.campaign.store import CampaignDataError, load_flight
    good = tmp_path / "good.npz"
    names = ("truth_t_us", "truth_pos", "uwb_kind", "uwb_t_us", "uwb_anchor_a", "uwb_anchor_b", "uwb_value",
             "uwb_true_value", "anchor_ids", "anchor_pos")
    np.savez(good, meta=np.array("{}"), **{n: np.arange(2000.0) for n in names})   # type: ignore[arg-type]
    data = good.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:100])
    flipped = bytearray(data)
    flipped[len(data) // 3:len(data) // 3 + 64] = bytes(b ^ 0x55 for b in flipped[len(data) // 3:len(data) // 3 + 64])
    (tmp_path / "flipped.npz").write_bytes(bytes(flipped))
    for name in ("cut.npz", "flipped.npz"):
        with pytest.raises(CampaignDataError, match=f"{name}: not a readable flight file"):
            load_flight(tmp_path / name)


def test_a_binary_campaign_json_is_a_named_data_error(tmp_path: Path) -> None:
    """campaign.json or runs/*.json overwritten with binary bytes: CampaignDataError (exit 2), not a
    UnicodeDecodeError (exit 4)."""
    from harness.campaign.store import CampaignDataError, read_json
    f = tmp_path / "campaign.json"
    f.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CampaignDataError, match="campaign.json: not a UTF-8 text file"):
        read_json(f)


def test_a_deleted_or_damaged_flight_file_is_flown_again_on_resume(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """The report reads DIR/flights/<flight>.npz: with it deleted or bit-flipped, a resume whose runs were all
    complete used to stop on it (exit 2, nothing to do but delete the runs too); now the flight runs again and
    writes it anew."""
    from harness.paths import DEFAULT_FIRMWARE
    if not DEFAULT_FIRMWARE.exists():
        pytest.skip("host firmware not built (make firmware)")
    out = tmp_path / "c"
    argv = ["campaign", "--out", str(out), "--seeds", "1", "--modes", "twr", "--trajectories", "circle",
            "--configs", "outlier", "--duration", "11", "--no-recorded", "--no-latency-runs"]
    assert main(argv) == 0
    flight = out / "flights" / "sim-twr-circle-s1000.npz"
    for damage in ("flip", "delete"):
        if damage == "flip":
            data = bytearray(flight.read_bytes())
            data[len(data) // 2] ^= 0xFF
            flight.write_bytes(bytes(data))
        else:
            flight.unlink()
        capsys.readouterr()
        assert main(argv) == 0, damage
        err = capsys.readouterr().err
        assert "0 already complete, 1 to run" in err, err
        assert flight.is_file()
    capsys.readouterr()
    assert main(argv) == 0
    assert "1 already complete, 0 to run" in capsys.readouterr().err
