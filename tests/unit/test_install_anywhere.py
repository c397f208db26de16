"""A package that installs anywhere (issue 27): the host firmware compiled from the shipped sources into a
per-user cache keyed by their hash, `uwb-hil --version`, `--help` in groups with defaults, complete metadata.
The whole route (wheel -> fresh virtualenv outside the checkout -> run and demo) is
scripts/check_wheel_install.sh, part of `make test-light-install`."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from harness import cli
from harness.firmware_cache import (FirmwareBuildError, cached_host_firmware, firmware_source_version,
                                    source_hash)
from harness.paths import FIRMWARE_DIR, REPO_ROOT
from protocol import PROTOCOL_VERSION

needs_cc = pytest.mark.skipif(not any(shutil.which(c) for c in ("cc", "gcc", "clang")), reason="no C compiler")


@needs_cc
def test_the_firmware_is_built_once_into_the_cache_keyed_by_the_sources(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWB_HIL_CACHE", str(tmp_path / "cache"))
    src = tmp_path / "src"
    shutil.copytree(FIRMWARE_DIR, src, ignore=shutil.ignore_patterns("build", "stm32", "fuzz", "tests", "*.npz"))
    exe = cached_host_firmware(src)
    assert exe == tmp_path / "cache" / "firmware" / source_hash(src) / "uwb-fw" and os.access(exe, os.X_OK)
    mtime = exe.stat().st_mtime_ns
    assert cached_host_firmware(src) == exe and exe.stat().st_mtime_ns == mtime      # reused, not rebuilt
    probe = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=10)
    assert probe.returncode == 2 and "uwb-hil protocol" in probe.stderr
    (src / "core" / "ekf_core.c").write_text((src / "core" / "ekf_core.c").read_text() + "\n/* edited */\n")
    assert cached_host_firmware(src) != exe                     # other sources: another cache entry


def test_without_a_compiler_the_error_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("UWB_HIL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(FirmwareBuildError, match=r"needs a C compiler: none found \(\$CC=/nonexistent/cc\)"):
        cached_host_firmware(FIRMWARE_DIR)


def test_version_names_package_protocol_and_firmware(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out.strip()
    assert re.fullmatch(rf"uwb-hil \S+, protocol {PROTOCOL_VERSION}, firmware \d+\.\d+\.\d+", out), out
    assert out.endswith(firmware_source_version())


def _run_parser() -> argparse.ArgumentParser:
    sub = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["run"]


def test_run_help_groups_its_options_and_shows_every_default() -> None:
    parser = _run_parser()
    groups = {g.title: {a.dest for a in g._group_actions} for g in parser._action_groups}
    for title, some in (("device", "port"), ("flight", "duration"), ("stages", "stages"), ("verdict", "max_rmse"),
                        ("output", "results")):
        assert some in groups.get(title, set()), (title, groups.keys())
    assert groups.get("options", set()) <= {"help"}           # nothing left ungrouped
    text = " ".join(parser.format_help().split())          # unwrapped
    missing = [a.dest for a in parser._actions if a.option_strings and a.default not in (None, False, [],
               argparse.SUPPRESS) and f"default: {a.default}" not in text and "default" not in (a.help or "")]
    assert missing == []
    assert "(default: outlier+nn)" in text and "(default: windowed)" in text


def test_pyproject_metadata_is_complete() -> None:
    meta = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    assert meta["license"] and (REPO_ROOT / meta["license-files"][0]).is_file()
    assert len(meta["classifiers"]) >= 5 and any(c.startswith("Framework :: Pytest") for c in meta["classifiers"])
    data = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "core/*.c" in data["uwb_hil_firmware"] and "models/*.h" in data["uwb_hil_firmware"]
