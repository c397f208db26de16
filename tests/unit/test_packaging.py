"""The light install: PyTorch is the [train] extra. Nothing imports it at import time, the flight commands
work without it, and the commands that need it say how to install it (exit 2). The full fresh-virtualenv
check is `make test-light-install` (scripts/check_light_install.sh, part of `make test`)."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from harness.cli import main
from harness.paths import DEFAULT_FIRMWARE, REPO_ROOT

FIX = REPO_ROOT / "tests" / "fixtures" / "recordings"
# `import torch` raises ImportError once sys.modules["torch"] is None: torch made unimportable
BLOCK_TORCH = "import sys; sys.modules['torch'] = None\n"


def _python(code: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", BLOCK_TORCH + code], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_pyproject_makes_torch_an_extra_with_a_lower_bound() -> None:
    meta = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    assert not any(d.replace(" ", "").startswith("torch") for d in meta["dependencies"])
    extras = meta["optional-dependencies"]
    assert extras["train"] == ["torch>=2.1"]
    assert any(d.startswith("pytest-timeout") for d in extras["test"])
    assert "tomli>=1.1; python_version<'3.11'" in meta["dependencies"]
    assert any(d.startswith("pyyaml") for d in meta["dependencies"])
    pins = (REPO_ROOT / "constraints.txt").read_text().split()
    assert "torch==2.13.0" in pins


def test_no_harness_module_imports_torch_at_import_time() -> None:
    code = """
import importlib, pkgutil, harness, protocol
failed = []
for pkg in (harness, protocol):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        try:
            importlib.import_module(m.name)
        except ImportError as exc:
            failed.append(f"{m.name}: {exc}")
print(len(list(pkgutil.walk_packages(harness.__path__))), failed)
assert not failed, failed
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("argv,what", [
    (["train", "--mode", "twr", "--flights", "2", "--duration", "5", "--out", "m.npz"], "uwb-hil train"),
    (["models", "--quick", "--only", "sim"], "uwb-hil models"),
])
def test_training_commands_without_torch_say_how_to_install_it(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str], argv: list[str],
                                                               what: str) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"uwb-hil: error: {what}") and "pip install 'uwb-hil[train]'" in err
    assert len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []       # refused before doing anything


def test_bench_agreement_check_without_torch_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch) -> None:
    import numpy as np

    from harness.bench.qemu_nn import NetTables, torch_reference
    from harness.optional import MissingDependencyError
    monkeypatch.setitem(sys.modules, "torch", None)
    net = NetTables.from_floats(3, np.zeros(3 + 3 + 150 + 50 + 2500 + 50 + 50 + 3, np.float32))
    with pytest.raises(MissingDependencyError, match=r"uwb-hil\[train\]"):
        torch_reference(net, np.zeros((2, 3)))


@pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")
def test_demo_and_run_work_without_torch() -> None:
    code = f"""
from harness.cli import main
assert main(["demo", "--duration", "3", "--json"]) == 0
assert main(["run", "--recording", {str(FIX / 'const1-fixture-tdoa2.csv')!r}, "--anchors",
             {str(FIX / 'anchors.csv')!r}, "--stages", "outlier", "--json"]) == 0
assert "torch" not in sys.modules or sys.modules["torch"] is None
"""
    proc = _python(code, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    docs = proc.stdout.replace("}\n{", "}\n\x00{").split("\x00")
    demo, run = json.loads(docs[0]), json.loads(docs[1])
    assert len(demo["runs"]) >= 6 and all(r["accuracy"]["rmse"] < 0.5 for r in demo["runs"])   # modes x 3 configs
    assert run["results"] == run["measurements"] > 0


def test_train_works_with_the_train_extra(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The other half of the light-install check: with [train] installed (make installs it), train works."""
    pytest.importorskip("torch", reason="the [train] extra is not installed")
    from harness.biasnet.network import BiasModel
    out = tmp_path / "m.npz"
    assert main(["train", "--mode", "twr", "--flights", "3", "--duration", "10", "--epochs", "3", "--out", str(out),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert BiasModel.load(out).hash_hex == doc["hash"] and doc["epochs"] == 3
    assert doc["n_train"] > 1000 and 0.0 < doc["val_rmse_after_m"] < 0.5
