"""The QEMU device's semihosting link (docs/qemu.md "The semihosting link"): uwb-fw-semihost.elf moves whole
blocks between two FIFOs and guest memory (ARM semihosting SYS_READ/SYS_WRITE) instead of one byte per QEMU
main-loop iteration through the emulated USART. Same frames, same firmware core: a real flight's slice gives the
same RESULTs (statuses, estimates, per-stage instruction counts) and the same RMSE as over the USART. The shipped
image stays free of semihosting. Skipped with the reason when the toolchain/QEMU or the shared data is absent."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from harness.device.qemu import QemuDevice, QemuOptions
from harness.device.registry import DeviceSpec, create_device, open_device
from harness.errors import DeviceError, UsageError
from harness.paths import shared_data_dir
from protocol.messages import CostUnit

FLIGHT = shared_data_dir() / "cf_usd" / "0425" / "0425-traj3"
# 2.5 s of the flight phase (~1,000 TDoA, ~2,400 IMU frames): ~8 s over the USART, ~0.1 s by semihosting
SLICE_S = (12.0, 14.5)


@pytest.fixture(scope="module")
def builds(arm_tools: None) -> Path:
    """uwb-fw.elf (the flashed image) and uwb-fw-semihost.elf (QEMU only), default model (make is incremental)."""
    from harness.stm32_build import build_stm32
    return build_stm32(("fw", "semihost"))


def _replay(elf: Path, link: str, flight: Any, log_dir: Path, icount: bool = True) -> tuple[Any, Any]:
    from harness.flight.run_config import run_estimator_config
    from harness.report.metrics import accuracy_summary
    from harness.stream.streamer import Pacing, Streamer
    cfg = run_estimator_config(flight, "outlier")
    spec = DeviceSpec(target="qemu", firmware=elf, qemu_link=link, log_dir=log_dir, timeout_s=20.0, qemu_icount=icount)
    with open_device(spec) as dev:
        run = Streamer(dev, timeout_s=60.0).run(flight, cfg, Pacing("windowed", 64))
        assert dev.link.info()["transport"].startswith("ARM semihosting" if link == "semihosting" else "QEMU -serial")
        assert dev.identity.cost_unit == (CostUnit.INSTRUCTIONS if icount else CostUnit.NANOSECONDS)
    return run, accuracy_summary(run, flight)


def test_semihosting_replay_gives_the_usart_replays_results(builds: Path, tmp_path: Path) -> None:
    if not FLIGHT.exists():
        pytest.skip(f"shared data absent ({FLIGHT})")
    from harness.flight.loaders import load_recording, time_slice
    flight = time_slice(load_recording(FLIGHT), *SLICE_S)
    usart, acc_usart = _replay(builds / "uwb-fw.elf", "usart", flight, tmp_path / "usart")
    semi, acc_semi = _replay(builds / "uwb-fw-semihost.elf", "semihosting", flight, tmp_path / "semi")
    a, b = usart.results, semi.results
    assert usart.n_received == semi.n_received == len(flight.uwb) > 800
    assert np.array_equal(a["status"], b["status"]) and np.array_equal(a["meas_seq"], b["meas_seq"])
    for f in ("px", "py", "pz", "qw", "var_x", "innovation", "bias"):
        np.testing.assert_allclose(b[f], a[f], rtol=0, atol=1e-6, err_msg=f)
    # the core's objects are the same in both ELFs: the same instructions per stage, whatever the link
    for f in ("cost_nn", "cost_gates", "cost_update"):
        assert np.median(b[f]) == np.median(a[f]), f
    assert acc_semi.n == acc_usart.n and abs(acc_semi.rmse - acc_usart.rmse) < 1e-6
    assert 0.05 < acc_usart.rmse < 1.0
    assert semi.wall_s < usart.wall_s / 3    # measured 0.1 s vs 7-8 s here (docs/qemu.md)
    # what the bench reads from QEMU's log: the guest's instruction count at the end of input, QEMU's CPU time
    from harness.bench.real_replay import CPU_RE, TICKS_RE
    log = "".join(p.read_text() for p in (tmp_path / "semi").glob("qemu-*.log"))
    ticks, cpu = TICKS_RE.search(log), CPU_RE.search(log)
    assert ticks and cpu, log[-500:]
    per_flight_s = int(ticks.group(1)) / semi.sim_s          # 6.77 M per flight second on the whole flight
    assert 3e6 < per_flight_s < 15e6 and 0 < float(cpu.group(1)) < 30


def test_host_clock_replay_gives_the_same_estimates(builds: Path, tmp_path: Path) -> None:
    """--qemu-clock host (no -icount, the bench's timed replay): the same estimates as under -icount; only the
    cost fields change meaning (virtual ns that follow the host's clock, reported as NANOSECONDS)."""
    if not FLIGHT.exists():
        pytest.skip(f"shared data absent ({FLIGHT})")
    from harness.flight.loaders import load_recording, time_slice
    flight = time_slice(load_recording(FLIGHT), *SLICE_S)
    exact, acc_exact = _replay(builds / "uwb-fw-semihost.elf", "semihosting", flight, tmp_path / "icount")
    fast, acc_fast = _replay(builds / "uwb-fw-semihost.elf", "semihosting", flight, tmp_path / "host", icount=False)
    a, b = exact.results, fast.results
    assert exact.n_received == fast.n_received == len(flight.uwb)
    assert np.array_equal(a["status"], b["status"])
    for f in ("px", "py", "pz", "qw", "var_x", "innovation"):
        assert np.array_equal(a[f], b[f]), f        # the same guest code on the same input: the same floats
    assert acc_fast.rmse == acc_exact.rmse
    log = "".join(p.read_text() for p in (tmp_path / "host").glob("qemu-*.log"))
    assert "-icount" not in log.splitlines()[0] and "-icount" in next((tmp_path / "icount").glob("qemu-*.log")).read_text()


def test_shipped_image_has_no_semihosting_and_the_links_refuse_the_wrong_build(builds: Path, tmp_path: Path) -> None:
    lst = subprocess.run(["arm-none-eabi-objdump", "-d", str(builds / "uwb-fw.elf")], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    semi = subprocess.run(["arm-none-eabi-objdump", "-d", str(builds / "uwb-fw-semihost.elf")], capture_output=True,
                          text=True, timeout=60, check=True).stdout
    assert "bkpt\t0x00ab" in semi and "bkpt" not in lst and "semihost" not in lst
    with pytest.raises(UsageError, match="has no semihosting link"):     # an input error: exit 2
        create_device(DeviceSpec(target="qemu", firmware=builds / "uwb-fw.elf", qemu_link="semihosting"))
    with pytest.raises(UsageError, match="is the semihosting build"):
        create_device(DeviceSpec(target="qemu", firmware=builds / "uwb-fw-semihost.elf"))
    with pytest.raises(DeviceError, match="has no semihosting link"):      # a device built directly
        QemuDevice(builds / "uwb-fw.elf", log_dir=tmp_path, options=QemuOptions(link="semihosting")).start()
    with pytest.raises(UsageError, match="unknown QEMU link 'jtag'"):
        create_device(DeviceSpec(target="qemu", qemu_link="jtag"))
    with pytest.raises(UsageError, match="semihosting link is QEMU's: use it with target qemu, not host"):
        create_device(DeviceSpec(qemu_link="semihosting"))
    assert DeviceSpec(target="qemu", qemu_link="semihosting").firmware_path() == builds / "uwb-fw-semihost.elf"
    with pytest.raises(UsageError, match="QEMU clock option is QEMU's: use it with target qemu, not host"):
        create_device(DeviceSpec(qemu_icount=False))
