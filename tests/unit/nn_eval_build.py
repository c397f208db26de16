"""firmware_sim/tools/nn_eval (the network alone, not a firmware: a test tool) built against an exported
model header by the firmware Makefile's nn_eval target (test_biasnet.py, test_quantize.py)."""

from __future__ import annotations

from pathlib import Path

from harness.firmware_build import run_make
from harness.paths import FIRMWARE_DIR


def build_nn_eval(header: Path, out: Path, timeout_s: float = 120.0) -> Path:
    """firmware_sim/tools/nn_eval compiled against ``header`` (an exported model) into ``out``."""
    out = Path(out).resolve()
    run_make(["-C", str(FIRMWARE_DIR), f"MODEL_HEADER={Path(header).resolve()}", f"NN_EVAL={out}", str(out)],
             timeout_s)
    return out
