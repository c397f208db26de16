"""The firmware built for the Crazyflie's MCU (STM32F405, Cortex-M4F) and run under QEMU.

Checks the board layer on its own (boot, FPU, instruction clock, a lossless 8-bit link), then flies the
same short TWR and TDoA flights through QEMU and through the host firmware and requires the same
decision on every measurement and the same estimates within float tolerance. Skipped, with the reason,
when the ARM toolchain or QEMU is missing and cannot be installed (scripts/ensure_arm_tools.sh).
"""

from __future__ import annotations

import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
STM32_DIR = REPO_ROOT / "firmware_sim" / "stm32"
BUILD = REPO_ROOT / "firmware_sim" / "build" / "stm32"
POS_TOL_M = 1e-3

pytestmark = pytest.mark.timeout(600)


def _tools_present() -> bool:
    return all(shutil.which(t) for t in ("arm-none-eabi-gcc", "arm-none-eabi-size", "qemu-system-arm"))


@pytest.fixture(scope="session")
def arm_tools() -> None:
    """The toolchain and QEMU, installed on demand (idempotent script); skip if that is impossible."""
    if _tools_present():
        return
    script = REPO_ROOT / "scripts" / "ensure_arm_tools.sh"
    try:
        proc = subprocess.run(["bash", str(script)], capture_output=True, text=True, timeout=900)
    except (OSError, subprocess.TimeoutExpired) as exc:
        pytest.skip(f"ARM toolchain/QEMU missing and {script.name} could not run: {exc}")
    if proc.returncode != 0 or not _tools_present():
        pytest.skip("ARM toolchain/QEMU (gcc-arm-none-eabi, libnewlib-arm-none-eabi, qemu-system-arm) missing "
                    f"and could not be installed: {(proc.stderr or proc.stdout).strip()[-400:]}")


def _make(*targets: str) -> Path:
    proc = subprocess.run(["make", "-s", "-C", str(STM32_DIR), *targets], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, f"STM32 build ({' '.join(targets)}) failed:\n{proc.stdout[-3000:]}\n" \
                                 f"{proc.stderr[-3000:]}"
    return BUILD


@pytest.fixture(scope="session")
def stm32_selftest(arm_tools: None) -> Path:
    """selftest.elf: the board layer alone."""
    return _make("selftest")


@pytest.fixture(scope="session")
def stm32_build(arm_tools: None) -> Path:
    """uwb-fw.elf and uwb-nnbench.elf (make is incremental)."""
    return _make("fw", "nnbench")


@pytest.fixture
def qemu_log(tmp_path: Path) -> Path:
    return tmp_path / "qemu.log"


def _read_until(link: Any, pred: Any, timeout: float) -> bytes:
    buf = b""
    deadline = time.monotonic() + timeout
    while not pred(buf) and time.monotonic() < deadline:
        buf += link.read(65536, 0.05)
    return buf


def test_board_layer_boots_with_fpu_and_instruction_clock(stm32_selftest: Path, qemu_log: Path) -> None:
    from harness.device.qemu import PtyLink, QemuProcess
    proc = QemuProcess(stm32_selftest / "selftest.elf", qemu_log)
    proc.start()
    try:
        assert proc.pty_path is not None
        link = PtyLink(proc.fd, proc.pty_path)
        banner = _read_until(link, lambda b: b.endswith(b"\n"), 5.0).decode(errors="replace")
        m = re.search(r"emulated=(\d) dwt=(\d) sysclk=(\d+) fpu=(0x[0-9a-f]+) busy1000=(\d+)", banner)
        assert m, f"no self-test banner: {banner!r} (log {qemu_log})"
        assert m.group(1) == "1" and m.group(2) == "0"      # QEMU: no RCC model, no DWT
        assert m.group(4) == "0x40580000"                     # 1.5f * 2.25f = 3.375f in the FPU
        # busy(1000) executes exactly 2000 loop instructions: TIM2 counts instructions under -icount.
        assert 2000 <= int(m.group(5)) <= 2050
        data = bytes(b for b in range(256) if b != ord("B")) * 16   # 4 KiB, more than the RX ring
        link.write(data)
        echo = _read_until(link, lambda b: len(b) >= len(data), 10.0)
        assert echo == data
        # Costs exclude interrupt time: a busy loop costs the same with link bytes arriving meanwhile.
        link.write(b"B")
        quiet = _read_until(link, lambda b: b.endswith(b"\n"), 5.0)
        link.write(b"B" + b"x" * 300)
        busy = _read_until(link, lambda b: b.count(b"x") >= 300 and b"\n" in b, 10.0)
        assert quiet.startswith(b"B=2000") and busy.startswith(quiet), (quiet, busy[:20])
    finally:
        proc.stop()


# ------------------------------------------------------------------------------------------ flights
@pytest.fixture(scope="module")
def devices(stm32_build: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    from harness.session import DeviceSpec, open_device
    log_dir = tmp_path_factory.mktemp("qemu-logs")
    with open_device(DeviceSpec(target="emulator")) as host, \
            open_device(DeviceSpec(target="qemu", log_dir=log_dir)) as qemu:
        yield {"host": host, "qemu": qemu}


def _flight(mode: str, duration_s: float = 2.0, seed: int = 21) -> Any:
    from harness.bench_qemu import flight_for
    return flight_for(mode, duration_s, seed)


def test_qemu_hello_reports_instruction_costs_and_same_model(devices: dict[str, Any]) -> None:
    qh = devices["qemu"].hello(timeout=5.0)
    hh = devices["host"].hello(timeout=5.0)
    assert qh.target.rstrip(b"\x00") == b"stm32f4"
    assert int(qh.cost_unit) == 1                             # instructions
    assert int(hh.cost_unit) == 0                             # nanoseconds
    assert qh.model_hash == hh.model_hash
    assert (qh.layout_twr, qh.layout_tdoa) == (hh.layout_twr, hh.layout_tdoa)
    assert qh.proto_version == hh.proto_version


@pytest.mark.parametrize("mode", ["twr", "tdoa"])
def test_qemu_flight_equals_host_firmware(devices: dict[str, Any], mode: str) -> None:
    from harness.config import PRESETS, EstimatorConfig
    from harness.session import config_for
    from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer

    flight = _flight(mode)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    runs = {name: Streamer(dev, timeout_s=20.0).run(flight, cfg, Pacing("windowed", 16))
            for name, dev in devices.items()}
    q, h = runs["qemu"].results, runs["host"].results
    n = len(flight.uwb)
    assert runs["qemu"].n_received == runs["host"].n_received == n
    assert np.all(q["outcome"] == OUTCOME_RESULT) and np.all(h["outcome"] == OUTCOME_RESULT)
    # Same decision on every measurement (accepted / which gate rejected it).
    bad = np.nonzero(q["status"] != h["status"])[0]
    assert len(bad) == 0, f"status differs at measurements {bad[:10].tolist()}"
    for key in ("px", "py", "pz"):
        diff = np.abs(q[key].astype(np.float64) - h[key].astype(np.float64))
        assert diff.max() < POS_TOL_M, f"{key}: max |qemu - host| = {diff.max():.2e} m"
    # The network ran on the emulated MCU and its cost is in instructions.
    assert np.any(q["bias"] != 0.0)
    assert np.max(np.abs(q["bias"].astype(np.float64) - h["bias"].astype(np.float64))) < 1e-4
    used = q["cost_nn"] > 0
    assert used.any()
    assert np.all(q["compute"][used] > q["cost_nn"][used])
    assert np.all(q["cost_update"][q["status"] == 0] > 0)


def test_qemu_costs_are_deterministic(devices: dict[str, Any]) -> None:
    """Under -icount every stage costs the same instructions when the same data is replayed."""
    from harness.config import PRESETS, EstimatorConfig
    from harness.session import config_for
    from harness.stream.streamer import Pacing, Streamer

    flight = _flight("tdoa")
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    streamer = Streamer(devices["qemu"], timeout_s=20.0)
    a = streamer.run(flight, cfg, Pacing("windowed", 16)).results
    b = streamer.run(flight, cfg, Pacing("lockstep")).results
    for key in ("cost_nn", "cost_gates", "cost_update", "compute", "px", "status"):
        assert np.array_equal(a[key], b[key]), key


def test_m4_network_kernels_match_pytorch_and_are_faster(stm32_build: Path, tmp_path: Path) -> None:
    from harness.bench_qemu import NN_TOLERANCE, network_kernels
    rows = network_kernels(n_inputs=25, seed=5, log_dir=tmp_path)
    assert rows, "the compiled-in model has no network"
    for r in rows:
        assert r.max_err_torch <= NN_TOLERANCE, r
    for kind in {r.kind for r in rows}:
        ladder = [r for r in rows if r.kind == kind]
        assert ladder[-1].instructions < ladder[0].instructions / 2, ladder
