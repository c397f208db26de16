"""Builds for the QEMU/STM32 checks: the ARM toolchain, the STM32F405 firmware, and a probe bias model.

The shipped default model may be untrained (its output layer is zero, so every bias is exactly 0 m) or
saturate its output clamp for many inputs; either would make "the MCU's network equals the host's" or
"equals PyTorch" true without testing anything. The probe model is a random network whose outputs stay
well inside its clamp range over the input box, compiled into both firmwares by
harness/firmware_build.py (MODEL_HEADER, the same route a trained model takes), so every bias the two
firmwares compare is a real, non-zero network output.

    python -m harness.stm32_build --tools                 # install the toolchain + QEMU when missing
    python -m harness.stm32_build --probe-header /tmp/p.h # the probe model as a C header
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from harness.firmware_build import BuildError, build_firmware
from harness.paths import FIRMWARE_DIR, REPO_ROOT

if TYPE_CHECKING:
    from harness.biasnet.network import BiasModel

FW_DIR = FIRMWARE_DIR
STM32_DIR = FW_DIR / "stm32"
ENSURE_SCRIPT = REPO_ROOT / "scripts" / "ensure_arm_tools.sh"
ARM_TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-size", "arm-none-eabi-nm", "qemu-system-arm")

__all__ = ["BuildError", "build_host", "build_host_with_model", "build_stm32", "build_stm32_with_model",
           "ensure_tools", "probe_model", "tools_present"]


def tools_present() -> bool:
    return all(shutil.which(t) for t in ARM_TOOLS)


def ensure_tools(install: bool = True, timeout_s: float = 900.0) -> None:
    """Make sure the ARM toolchain and QEMU exist (scripts/ensure_arm_tools.sh installs them with apt)."""
    if tools_present():
        return
    env = dict(os.environ)
    if not install:
        env["UWB_NO_INSTALL"] = "1"
    try:
        proc = subprocess.run(["bash", str(ENSURE_SCRIPT)], capture_output=True, text=True, timeout=timeout_s,
                              env=env)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise BuildError(f"{ENSURE_SCRIPT.name} could not run: {exc}") from exc
    if proc.returncode != 0 or not tools_present():
        missing = [t for t in ARM_TOOLS if not shutil.which(t)]
        raise BuildError(f"ARM toolchain/QEMU missing ({', '.join(missing)}) and {ENSURE_SCRIPT.name} could not "
                         f"install them: {(proc.stderr or proc.stdout).strip()[-600:]}")


def build_stm32(targets: tuple[str, ...] = ("fw",), build_dir: Path | None = None, model_header: Path | None = None,
                nn_impl: str = "m4", make_vars: tuple[str, ...] = (), timeout_s: float = 600.0) -> Path:
    """`make -C firmware_sim/stm32 <targets>` (incremental); returns the build directory.

    With a model header or other make variables (UWB_USART=3, ...), build into a separate directory:
    the Makefile tracks neither."""
    return build_firmware("stm32", None, build_dir, model_header=model_header, make_targets=targets,
                          nn_impl=nn_impl, make_vars=make_vars, timeout_s=timeout_s)


def build_host(build_dir: Path, model_header: Path | None = None, timeout_s: float = 600.0) -> Path:
    """The host firmware (no sanitizers) into build_dir; returns the binary's path."""
    return build_firmware("host", None, build_dir, model_header=model_header, timeout_s=timeout_s)


# ------------------------------------------------------------------------------------------ probe model
@dataclass(frozen=True)
class ProbeSpec:
    seed: int = 2024
    half_room_m: float = 6.0          # dp features in [-half_room_m, half_room_m]
    out_half_range_m: float = 0.3     # clamp range [-0.3, 0.3] m
    target_std_m: float = 0.05        # spread of the bias over the input box
    samples: int = 4000


def probe_model(spec: ProbeSpec = ProbeSpec()) -> BiasModel:
    """Random TWR (6-in) and TDoA (9-in) networks, rescaled so the bias over the input box is centred on
    0 m with ~target_std_m spread: well inside the clamp, so the output clamp never hides the network."""
    from harness.biasnet.network import BiasModel, init_network  # noqa: F811 - runtime import
    from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POSE

    rng = np.random.default_rng(spec.seed)
    angles = np.array([np.pi / 4, np.pi / 4, np.pi], np.float32)
    nets = {}
    for kind, layout, n_dp in (("twr", LAYOUT_TWR_POSE, 3), ("tdoa", LAYOUT_TDOA_POSE, 6)):
        hi = np.concatenate([np.full(n_dp, spec.half_room_m, np.float32), angles])
        net = init_network(layout, -hi, hi, -spec.out_half_range_m, spec.out_half_range_m, rng)
        x = rng.uniform(-hi, hi, (spec.samples, hi.size))
        # Output before the de-scaling: y' = h2 . w3 + b3. Rescale w3 and pick b3 so that y' has mean
        # 0.5 (bias 0 m) and the wanted spread; the clamp sits 6 standard deviations away.
        xs = (x - net.in_min) / (net.in_max - net.in_min)
        h1 = np.maximum(xs @ net.w1 + net.b1, 0.0)
        y0 = np.maximum(h1 @ net.w2 + net.b2, 0.0) @ net.w3
        span = 2.0 * spec.out_half_range_m
        scale = (spec.target_std_m / span) / max(float(np.std(y0)), 1e-9)
        w3 = (net.w3 * scale).astype(np.float32)
        b3 = 0.5 - float(np.mean(y0)) * scale
        nets[kind] = replace(net, w3=w3, b3=b3)
    return BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name=f"qemu-probe-seed{spec.seed}")


def build_stm32_with_model(model: BiasModel, targets: tuple[str, ...], build_dir: Path,
                           nn_impl: str = "m4") -> Path:
    """The STM32 build with another bias model compiled in, in its own directory."""
    return build_firmware("stm32", model, build_dir, make_targets=targets, nn_impl=nn_impl)


def build_host_with_model(model: BiasModel, build_dir: Path) -> Path:
    """The host firmware with another bias model compiled in, in its own directory; returns the binary."""
    return build_firmware("host", model, build_dir)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tools", action="store_true", help="install the ARM toolchain and QEMU when missing")
    ap.add_argument("--probe-header", type=Path, default=None, help="write the probe model's C header here")
    args = ap.parse_args(argv)
    try:
        if args.tools:
            ensure_tools()
            print("ARM toolchain and QEMU present: " + ", ".join(ARM_TOOLS))
        if args.probe_header is not None:
            from harness.biasnet.export import export_c
            print(export_c(probe_model(), args.probe_header))
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
