"""Where things are in the repository checkout: the one place that knows the repository root."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
# a checkout's firmware_sim/, or in an installed package the same sources shipped as uwb_hil_firmware/
FIRMWARE_DIR = (REPO_ROOT / "firmware_sim" if (REPO_ROOT / "firmware_sim").is_dir()
                else REPO_ROOT / "uwb_hil_firmware")
FIRMWARE_BUILD_DIR = FIRMWARE_DIR / "build"
MODELS_DIR = FIRMWARE_DIR / "models"
DEFAULT_FIRMWARE = FIRMWARE_BUILD_DIR / "uwb-fw"                  # the host build (`make firmware`)
DEFAULT_ASAN_FIRMWARE = FIRMWARE_BUILD_DIR / "uwb-fw-asan"        # the same with ASan + UBSan (`make firmware`)
DEFAULT_STM32_ELF = FIRMWARE_BUILD_DIR / "stm32" / "uwb-fw.elf"   # the STM32F405 image (`make stm32`)
#: the same firmware with its link over ARM semihosting: QEMU only, never flashed (`make stm32`, docs/qemu.md)
DEFAULT_STM32_SEMIHOST_ELF = FIRMWARE_BUILD_DIR / "stm32" / "uwb-fw-semihost.elf"
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"                # the recordings, beside the checkout


def shared_data_dir() -> Path:
    """The shared recordings: $UWB_HIL_DATA, else SHARED_DATA (../shared/data beside the checkout)."""
    return Path(os.environ.get("UWB_HIL_DATA", SHARED_DATA))


def same_file_as_input(output: Path, inputs: "list[str | Path | None]") -> str | None:
    """The input `output` would overwrite: the same file (by inode, whatever the path: links, `..`), or a
    file inside an input directory (a recording folder); None when it is none of them."""
    out = Path(output)
    if not out.exists():
        return None
    real = out.resolve()
    for item in inputs:
        if not item:
            continue
        src = Path(str(item).lstrip("@"))
        try:
            if src.is_dir() and real.is_relative_to(src.resolve()):
                return str(item)
            if src.exists() and os.path.samefile(out, src):
                return str(item)
        except OSError:
            continue
    return None


def output_path(path: str | Path, option: str, directory: bool = False) -> Path:
    """An output the user named (`--out FILE` or, with `directory`, `--out DIR`), checked before any work is
    done (so a long training or grid search is not lost at the end): a file must not be a directory, a
    directory not a file, and no folder above it may be a file. Missing folders are created."""
    from harness.errors import UsageError
    path = Path(path)
    if directory and path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path} is a file, not a directory")
    if not directory and path.is_dir():
        raise UsageError(f"{option} {path} is a directory: give a file name, e.g. {path / 'out'}")
    above = next((p for p in path.absolute().parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise UsageError(f"{option} {path}: {above} is a file, not a directory")
    try:
        path.absolute().parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot create its folder ({exc.strerror})") from None
    return path
