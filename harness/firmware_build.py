"""Firmware builds, and the one route a bias model takes into an image.

A firmware carries exactly one model (its tables are ``const``, in flash on the MCU), so another model means
another image. Both Makefiles take ``MODEL_HEADER=path`` (firmware_sim/Makefile: the host binary,
firmware_sim/stm32/Makefile: the STM32F405 images); ``build_firmware(target, model)`` exports the model's
header into the build directory and runs make there. The Makefiles do not know a header named on the
command line changed, so a changed model starts its build directory afresh; an unchanged one reuses it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

from harness.errors import UsageError, UwbHilError
from harness.paths import FIRMWARE_BUILD_DIR, FIRMWARE_DIR

if TYPE_CHECKING:
    from harness.biasnet.network import BiasModel

STM32_DIR = FIRMWARE_DIR / "stm32"
BUILD_TARGETS = ("host", "stm32")


class BuildError(UwbHilError, RuntimeError):
    """A firmware build or the toolchain installation failed (carries the tool's output)."""


def run_make(args: list[str], timeout_s: float) -> None:
    cmd = ["make", "-s", *args]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired as exc:
        raise BuildError(f"{' '.join(cmd)} did not finish within {timeout_s:.0f} s") from exc
    except OSError as exc:
        raise BuildError(f"{cmd[0]} could not run: {exc}") from exc
    if proc.returncode != 0:
        raise BuildError(f"{' '.join(cmd)} failed:\n{proc.stdout[-3000:]}{proc.stderr[-3000:]}")


def install_header(model: BiasModel, build_dir: Path) -> Path:
    """The model's header as build_dir/model/bias_model.h; a different model empties build_dir first."""
    from harness.biasnet.export import header_text
    header = Path(build_dir) / "model" / "bias_model.h"
    text = header_text(model)
    if not header.is_file() or header.read_text() != text:
        shutil.rmtree(build_dir, ignore_errors=True)
        header.parent.mkdir(parents=True)
        header.write_text(text)
    return header


def build_firmware(target: str, model: BiasModel | None = None, build_dir: Path | None = None, *,
                   model_header: Path | None = None, make_targets: tuple[str, ...] = ("fw",), nn_impl: str = "m4",
                   make_vars: tuple[str, ...] = (), timeout_s: float = 600.0) -> Path:
    """Build ``target`` ("host" or "stm32") with ``model`` (or an exported ``model_header``; neither: the
    shipped default) into ``build_dir``. Returns the host binary, or the STM32 build directory (uwb-fw.elf
    and the other ``make_targets`` in it). Incremental; a model, header or make variables need their own
    build_dir (firmware_sim/build/models/<hash>/<target> when not given for a model)."""
    if target not in BUILD_TARGETS:
        raise UsageError(f"build target must be one of {BUILD_TARGETS}, got {target!r}")
    if model is not None and model_header is not None:
        raise UsageError("give a model or a model header, not both")
    if build_dir is None:
        if model_header is not None or make_vars:
            raise UsageError("a build with a model header or make variables needs its own build_dir")
        build_dir = (FIRMWARE_BUILD_DIR / "models" / model.hash_hex / target if model is not None
                     else FIRMWARE_BUILD_DIR / ("stm32" if target == "stm32" else ""))
    build_dir = Path(build_dir).resolve()
    if model is not None:
        model_header = install_header(model, build_dir)
    header = [f"MODEL_HEADER={Path(model_header).resolve()}"] if model_header is not None else []
    if target == "host":
        exe = build_dir / "uwb-fw"
        run_make(["-C", str(FIRMWARE_DIR), f"BUILD={build_dir}", *header, *make_vars, str(exe)], timeout_s)
        if not exe.is_file():
            raise BuildError(f"make finished but {exe} is missing")
        return exe
    run_make(["-C", str(STM32_DIR), *make_targets, f"NN_IMPL={nn_impl}", f"BUILD={build_dir}", *header,
              *make_vars], timeout_s)
    return build_dir


def firmware_for(model: BiasModel, build_root: Path | None = None, timeout_s: float = 300.0) -> Path:
    """The host firmware binary carrying ``model``: built once into build_root/<hash> (default
    firmware_sim/build/models/<hash>), later calls reuse it."""
    out = (build_root or FIRMWARE_BUILD_DIR / "models") / model.hash_hex
    return build_firmware("host", model, out, timeout_s=timeout_s)

