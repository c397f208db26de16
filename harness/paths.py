"""Where things are in the repository checkout: the one place that knows the repository root."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
FIRMWARE_DIR = REPO_ROOT / "firmware_sim"
FIRMWARE_BUILD_DIR = FIRMWARE_DIR / "build"
MODELS_DIR = FIRMWARE_DIR / "models"
DEFAULT_FIRMWARE = FIRMWARE_BUILD_DIR / "uwb-fw"                  # the host build (`make firmware`)
DEFAULT_ASAN_FIRMWARE = FIRMWARE_BUILD_DIR / "uwb-fw-asan"        # the same with ASan + UBSan (`make firmware`)
DEFAULT_STM32_ELF = FIRMWARE_BUILD_DIR / "stm32" / "uwb-fw.elf"   # the STM32F405 image (`make stm32`)
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"                # the recordings, beside the checkout


def shared_data_dir() -> Path:
    """The shared recordings: $UWB_HIL_DATA, else SHARED_DATA (../shared/data beside the checkout)."""
    return Path(os.environ.get("UWB_HIL_DATA", SHARED_DATA))
