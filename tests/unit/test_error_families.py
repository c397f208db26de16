"""Errors: every error class the harness raises for bad input is an InputError (a UwbHilError, exit 2); a
device or link failure exits 3; anything else reaching a command is a bug: exit 4, one line saying so and
naming the file its traceback was written to."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from harness import cli
from harness.errors import (EXIT_BUG, EXIT_DEVICE, EXIT_INPUT, DeviceTimeout, InputError, InputFileNotFound,
                            LinkClosed, UsageError, UwbHilError, exit_code, report_failure)

ROOT = Path(__file__).resolve().parents[2]


def _error_classes() -> list[tuple[str, str]]:
    """(module, class) of every public exception class defined in harness/ (a base named ...Error)."""
    found = []
    for f in sorted((ROOT / "harness").rglob("*.py")):
        module = ".".join(f.relative_to(ROOT).with_suffix("").parts)
        for node in ast.parse(f.read_text()).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_") and any(
                    getattr(b, "id", getattr(b, "attr", "")).endswith(("Error", "Exception", "NotFound"))
                    for b in node.bases):
                found.append((module, node.name))
    return found


def test_every_value_error_of_the_harness_is_an_input_error() -> None:
    classes = _error_classes()
    assert len(classes) > 25
    outside = []
    for module, name in classes:
        cls = getattr(importlib.import_module(module), name)
        if issubclass(cls, ValueError) and not issubclass(cls, InputError):
            outside.append(f"{module}.{name}")
        if not issubclass(cls, UwbHilError):
            outside.append(f"{module}.{name} (not a UwbHilError)")
    assert outside == []


def test_exit_codes_by_family() -> None:
    assert exit_code(UsageError("x")) == exit_code(InputFileNotFound("x")) == EXIT_INPUT == 2
    assert exit_code(DeviceTimeout("x")) == exit_code(LinkClosed("x")) == EXIT_DEVICE == 3
    assert exit_code(OSError(28, "No space left on device")) == EXIT_INPUT
    assert exit_code(ValueError("x")) == exit_code(KeyError("x")) == EXIT_BUG == 4
    assert isinstance(InputFileNotFound("x"), FileNotFoundError)     # `except FileNotFoundError` still holds


def test_an_input_error_is_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--set", "std_twr=0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uwb-hil: error: ") and "std_twr must be > 0" in err and "Traceback" not in err


def test_a_bug_is_exit_4_with_its_traceback_in_a_file(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    def broken(args: object) -> int:
        raise KeyError("a dict the harness should have filled")

    monkeypatch.setattr(cli, "cmd_ports", broken)
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    assert cli.main(["ports"]) == 4
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert err.startswith("uwb-hil: internal error (a bug in uwb-hil, not in your input): KeyError:")
    written = sorted(tmp_path.glob("uwb-hil-bug-*.txt"))
    assert len(written) == 1 and f"traceback written to {written[0]}" in err
    text = written[0].read_text()
    assert "Traceback (most recent call last)" in text and "in broken" in text and "KeyError" in text


def test_a_bug_report_that_cannot_be_written_still_says_so(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    assert report_failure(RuntimeError("boom"), "tool", bug_dir=tmp_path / "missing") == 4
    err = capsys.readouterr().err
    assert "tool: internal error" in err and "RuntimeError: boom" in err and "traceback not written" in err
