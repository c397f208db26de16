"""Compile C with a given bias model: host firmware variants (cached by model hash) and the nn_eval tool.

A firmware carries exactly one model (its tables are ``const``, in flash on the MCU), so running with
another model means building another image: ``firmware_for(model)`` exports the header and builds
``firmware_sim/build/models/<hash>/uwb-fw`` once; later calls reuse it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from harness.biasnet.model import BiasModel
from harness.firmware_build import BuildError, build_firmware
from harness.paths import FIRMWARE_BUILD_DIR, FIRMWARE_DIR

__all__ = ["BuildError", "build_nn_eval", "firmware_for"]

FW_DIR = FIRMWARE_DIR
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wpointer-arith", "-Wstrict-prototypes",
          "-Wmissing-prototypes", "-O2"]


def _compiler() -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise BuildError("no C compiler (cc/gcc) on PATH")
    return cc


def firmware_for(model: BiasModel, build_root: Path | None = None, timeout_s: float = 300.0) -> Path:
    """The host firmware binary carrying ``model`` (built on first use)."""
    out = (build_root or FIRMWARE_BUILD_DIR / "models") / model.hash_hex
    return build_firmware("host", model, out, timeout_s=timeout_s)


def build_nn_eval(header: Path, out: Path, timeout_s: float = 120.0) -> Path:
    """firmware_sim/tools/nn_eval compiled against ``header`` (an exported model)."""
    cmd = [_compiler(), *CFLAGS, f"-DBIAS_MODEL_HEADER=\"{Path(header).resolve()}\"", "-Icore", "-Imodels",
           "-o", str(out), "core/bias_nn.c", "tools/nn_eval.c", "-lm"]
    proc = subprocess.run(cmd, cwd=FW_DIR, capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise BuildError(f"building nn_eval failed:\n{proc.stderr}")
    return Path(out)
