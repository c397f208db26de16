"""Settings files: `--set @FILE.toml` (harness.config.settings_file / config_with) and the shipped ones."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.config import EstimatorConfig, config_with, settings_file

SETTINGS_DIR = Path(__file__).resolve().parents[2] / "harness" / "settings"


def test_file_settings_apply_and_later_items_win(tmp_path: Path) -> None:
    f = tmp_path / "s.toml"
    f.write_text('# provenance\n[settings]\nproc_cv_acc = 1.0\nstd_tdoa = 0.2\n[source]\nwhy = "x"\n')
    assert settings_file(f) == ["proc_cv_acc=1.0", "std_tdoa=0.2"]
    cfg = config_with([f"@{f}", "std_tdoa=0.3"])
    assert cfg.proc_cv_acc == pytest.approx(1.0)
    assert cfg.std_tdoa == pytest.approx(0.3)
    assert cfg.std_twr == EstimatorConfig().std_twr   # untouched fields keep the power-up value


@pytest.mark.parametrize("text, why", [
    ("[settings]\nnot_a_field = 1.0\n", r"^settings file .*bad\.toml: 'not_a_field=1\.0': expected FIELD=VALUE"),
    ("[settings]\nproc_cv_acc = -1.0\n", "proc_cv_acc"),
    ("[other]\nx = 1\n", "no \\[settings\\] table"),
    ("[settings\n", "settings file"),
    ("nn_min_z = -1.0\n[settings]\nstd_tdoa = 0.3\n", "nn_min_z outside the \\[settings\\] table"),
    ("[settings]\nstd_tdoa = \"0.3\"\n", "is not a number"),
    ("[settings]\nstd_tdoa = true\n", "is not a number"),
])
def test_bad_settings_files_are_refused_with_a_reason(tmp_path: Path, text: str, why: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ValueError, match=why):
        config_with([f"@{f}"])


def test_binary_settings_file_is_refused(tmp_path: Path) -> None:
    """A binary file as --set @FILE: a named input error (it was a UnicodeDecodeError, exit 4)."""
    f = tmp_path / "bin.toml"
    f.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ValueError, match="settings file .*bin.toml: not a UTF-8 text file"):
        config_with([f"@{f}"])


def test_missing_settings_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="settings file"):
        config_with([f"@{tmp_path / 'nope.toml'}"])


def test_shipped_settings_files_are_valid() -> None:
    files = sorted(SETTINGS_DIR.glob("*.toml"))
    assert files, "harness/settings/ holds the documented settings files"
    for f in files:
        items = settings_file(f)
        cfg = config_with([f"@{f}"])
        assert items and cfg != EstimatorConfig(), f"{f.name} changes nothing"


def test_results_header_names_the_settings_file_absolutely(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from harness.run.source import RunSource
    (tmp_path / "s.toml").write_text("[settings]\nstd_tdoa = 0.2\n")
    monkeypatch.chdir(tmp_path)
    header = RunSource(set=["@s.toml", "proc_cv_acc=1"]).as_header()
    assert header["set"] == [f"@{tmp_path / 's.toml'}", "proc_cv_acc=1"]
    monkeypatch.chdir("/")
    assert config_with(header["set"]).std_tdoa == pytest.approx(0.2)   # a resume elsewhere finds it
