"""Compile C with a given bias model: host firmware variants (cached by model hash) and the nn_eval tool.

A firmware carries exactly one model (its tables are ``const``, in flash on the MCU), so running with
another model means building another image: ``firmware_for(model)`` exports the header and builds
``firmware_sim/build/models/<hash>/uwb-fw`` once; later calls reuse it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from harness.biasnet.export import export_c
from harness.biasnet.model import BiasModel
from harness.paths import FIRMWARE_DIR

FW_DIR = FIRMWARE_DIR
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wpointer-arith", "-Wstrict-prototypes",
          "-Wmissing-prototypes", "-O2"]


class BuildError(RuntimeError):
    """The C compiler or make failed; the message carries its output."""


def _compiler() -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise BuildError("no C compiler (cc/gcc) on PATH")
    return cc


def firmware_for(model: BiasModel, build_root: Path | None = None, timeout_s: float = 300.0) -> Path:
    """The host firmware binary carrying ``model`` (built on first use)."""
    out = (build_root or FW_DIR / "build" / "models") / model.hash_hex
    exe = out / "uwb-fw"
    header = out / "bias_model.h"
    export_c(model, header)
    proc = subprocess.run(["make", "-s", "-C", str(FW_DIR), "fw", f"BUILD={out}", f"MODEL_HEADER={header}"],
                          capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0 or not exe.is_file():
        raise BuildError(f"building the firmware for model {model.hash_hex} failed:\n{proc.stdout}{proc.stderr}")
    return exe


def build_nn_eval(header: Path, out: Path, timeout_s: float = 120.0) -> Path:
    """firmware_sim/tools/nn_eval compiled against ``header`` (an exported model)."""
    cmd = [_compiler(), *CFLAGS, f"-DBIAS_MODEL_HEADER=\"{Path(header).resolve()}\"", "-Icore", "-Imodels",
           "-o", str(out), "core/bias_nn.c", "tools/nn_eval.c", "-lm"]
    proc = subprocess.run(cmd, cwd=FW_DIR, capture_output=True, text=True, timeout=timeout_s)
    if proc.returncode != 0:
        raise BuildError(f"building nn_eval failed:\n{proc.stderr}")
    return Path(out)
