"""One route for a bias model into a firmware build (harness/firmware_build.py), one BuildError."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from harness.errors import UwbHilError
from harness.firmware_build import BuildError, build_firmware, install_header
from harness.stm32_build import ProbeSpec, probe_model

ROOT = Path(__file__).resolve().parents[2]


def test_one_build_error_class_that_the_cli_reports() -> None:
    from harness import stm32_build
    assert stm32_build.BuildError is BuildError
    assert issubclass(BuildError, UwbHilError) and issubclass(BuildError, RuntimeError)


def test_only_firmware_build_passes_a_model_header_to_make() -> None:
    """The model header reaches make (MODEL_HEADER) or the compiler (-DBIAS_MODEL_HEADER) from one product
    module (the nn_eval test tool, not a firmware, is built by tests/unit/nn_eval_build.py)."""
    users = sorted(str(f.relative_to(ROOT)) for f in (ROOT / "harness").rglob("*.py")
                   if any(s in f.read_text() for s in ("MODEL_HEADER=", "EXTRA_CFLAGS", "[\"CFLAGS\"]")))
    assert users == ["harness/firmware_build.py"]


def test_bad_requests_are_refused_before_make(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="build target"):
        build_firmware("avr", None, tmp_path)
    with pytest.raises(ValueError, match="not both"):
        build_firmware("host", probe_model(), tmp_path, model_header=tmp_path / "m.h")
    with pytest.raises(ValueError, match="own build_dir"):
        build_firmware("stm32", None, None, model_header=tmp_path / "m.h")


def test_a_changed_model_starts_its_build_directory_afresh(tmp_path: Path) -> None:
    a, b = probe_model(), probe_model(ProbeSpec(seed=7))
    header = install_header(a, tmp_path / "b")
    (tmp_path / "b" / "stale.o").write_text("x")
    assert install_header(a, tmp_path / "b") == header and (tmp_path / "b" / "stale.o").exists()
    install_header(b, tmp_path / "b")
    assert not (tmp_path / "b" / "stale.o").exists() and header.read_text() != ""


def test_host_build_carries_the_model(tmp_path: Path) -> None:
    from harness.device.registry import DeviceSpec, open_device
    model = probe_model()
    exe = build_firmware("host", model, tmp_path / "host")
    with open_device(DeviceSpec(firmware=exe), expected_model_hash=model.hash) as dev:
        assert dev.identity.model_hash == model.hash


@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="no ARM toolchain")
def test_stm32_build_carries_the_model(tmp_path: Path) -> None:
    """The model's tables are in the ELF: its hash is compiled into the image the HELLO reply reports."""
    model = probe_model()
    out = build_firmware("stm32", model, tmp_path / "stm32")
    elf = (out / "uwb-fw.elf").read_bytes()
    assert model.hash.to_bytes(8, "little") in elf


def test_compiler_flags_live_in_the_makefiles_only() -> None:
    copies = sorted(str(f.relative_to(ROOT)) for f in (ROOT / "harness").rglob("*.py")
                    if "-Werror" in f.read_text() or "-std=c99" in f.read_text())
    assert not copies, f"compiler flags copied from the Makefiles into {copies}"
