"""Compile C with a given bias model: host firmware variants (cached by model hash) and the nn_eval tool.

A firmware carries exactly one model (its tables are ``const``, in flash on the MCU), so running with
another model means building another image: ``firmware_for(model)`` exports the header and builds
``firmware_sim/build/models/<hash>/uwb-fw`` once; later calls reuse it.
"""

from __future__ import annotations

from pathlib import Path

from harness.biasnet.network import BiasModel
from harness.firmware_build import BuildError, build_firmware, run_make
from harness.paths import FIRMWARE_BUILD_DIR, FIRMWARE_DIR

__all__ = ["BuildError", "build_nn_eval", "firmware_for"]


def firmware_for(model: BiasModel, build_root: Path | None = None, timeout_s: float = 300.0) -> Path:
    """The host firmware binary carrying ``model`` (built on first use)."""
    out = (build_root or FIRMWARE_BUILD_DIR / "models") / model.hash_hex
    return build_firmware("host", model, out, timeout_s=timeout_s)


def build_nn_eval(header: Path, out: Path, timeout_s: float = 120.0) -> Path:
    """firmware_sim/tools/nn_eval compiled against ``header`` (an exported model), by the Makefile's flags."""
    out = Path(out).resolve()
    run_make(["-C", str(FIRMWARE_DIR), f"MODEL_HEADER={Path(header).resolve()}", f"NN_EVAL={out}", str(out)],
             timeout_s)
    return out
