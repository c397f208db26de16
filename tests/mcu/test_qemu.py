"""The firmware built for the Crazyflie's MCU (STM32F405, Cortex-M4F) and run under QEMU.

Checks the board layer on its own (boot, FPU, instruction clock, a lossless 8-bit link), then flies the
same short TWR and TDoA flights through QEMU and through the host firmware and requires the same
decision on every measurement and the same estimates within float tolerance. Skipped, with the reason,
when the ARM toolchain or QEMU is missing and cannot be installed (scripts/ensure_arm_tools.sh).
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
POS_TOL_M = 1e-3

pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="session")
def stm32_selftest(arm_tools: None) -> Path:
    """selftest.elf: the board layer alone."""
    from harness.stm32_build import build_stm32
    return build_stm32(("selftest",))


@pytest.fixture(scope="session")
def stm32_build(arm_tools: None) -> Path:
    """The shipped build: uwb-fw.elf and uwb-nnbench.elf with firmware_sim/models (make is incremental)."""
    from harness.stm32_build import build_stm32
    return build_stm32(("fw", "nnbench"))


@pytest.fixture(scope="session")
def probe_builds(arm_tools: None, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Host and STM32 firmware with the probe model (non-zero, unclamped biases): the shipped model may
    be untrained (bias exactly 0 m), which would let the network comparison pass without testing it."""
    from harness.stm32_build import build_host_with_model, build_stm32_with_model, probe_model
    model = probe_model()
    base = tmp_path_factory.mktemp("probe-build")
    stm32 = build_stm32_with_model(model, ("fw", "nnbench"), base / "stm32")
    host = build_host_with_model(model, base / "host")
    return {"stm32": stm32, "host": host, "hash": model.hash}


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
    from harness.device.qemu import QemuProcess
    from harness.link.qemu_link import QemuPtyLink
    proc = QemuProcess(stm32_selftest / "selftest.elf", qemu_log)
    proc.start()
    try:
        assert proc.serial_name is not None
        link = QemuPtyLink(proc.fd, proc.serial_name)
        banner = _read_until(link, lambda b: b.endswith(b"\n"), 5.0).decode(errors="replace")
        m = re.search(r"emulated=(\d) dwt=(\d) sysclk=(\d+) fpu=(0x[0-9a-f]+) busy1000=(\d+)", banner)
        assert m, f"no self-test banner: {banner!r} (log {qemu_log})"
        assert m.group(1) == "1" and m.group(2) == "0"      # QEMU: no RCC model, no DWT
        assert m.group(4) == "0x40580000"                     # 1.5f * 2.25f = 3.375f in the FPU
        # busy(1000) executes exactly 2000 loop instructions: TIM2 counts instructions under -icount.
        assert 2000 <= int(m.group(5)) <= 2050
        # 80 KiB of every byte value in one write, nothing read meanwhile: more than the firmware's RX ring
        # and more than the pty buffers of the echo direction (~64 KiB). QEMU's USART transmits
        # synchronously, so the guest stalls while the host is not reading; the link drains the echo
        # while its write waits, otherwise host and guest would wait for each other.
        data = bytes(b for b in range(256) if b != ord("B")) * 320
        link.write(data)
        echo = _read_until(link, lambda b: len(b) >= len(data), 60.0)
        assert len(echo) == len(data) and echo == data
        # Costs exclude interrupt time: a busy loop costs the same with link bytes arriving meanwhile.
        link.write(b"B")
        quiet = _read_until(link, lambda b: b.endswith(b"\n"), 5.0)
        link.write(b"B" + b"x" * 300)
        busy = _read_until(link, lambda b: b.count(b"x") >= 300 and b"\n" in b, 10.0)
        assert quiet.startswith(b"B=2000") and busy.startswith(quiet), (quiet, busy[:20])
    finally:
        proc.stop()


def test_crazyflie_usart3_build_serves_the_protocol(arm_tools: None, tmp_path: Path) -> None:
    """The Crazyflie build's link (UWB_USART=3: expansion-deck UART1, PC10/PC11) is QEMU's serial2."""
    from harness.device.qemu import QemuDevice, QemuOptions
    from harness.errors import DeviceError
    from harness.stm32_build import build_stm32
    build = build_stm32(("fw",), tmp_path / "stm32-usart3", make_vars=("UWB_USART=3",))
    device = QemuDevice(build / "uwb-fw.elf", log_dir=tmp_path, options=QemuOptions(serial_index=2))
    device.start()
    try:
        hello = device.hello(timeout=5.0)
        assert hello.target.rstrip(b"\x00") == b"stm32f4" and int(hello.cost_unit) == 1
    finally:
        device.stop()
    # On USART1 (the default build's link) this build never enables a receiver: a clear start-up error.
    wrong = QemuDevice(build / "uwb-fw.elf", log_dir=tmp_path, options=QemuOptions(serial_index=0, start_timeout_s=3.0))
    with pytest.raises(DeviceError, match="did not enable its USART"):
        wrong.start()
    assert not wrong.alive()


def test_shipped_build_fits_the_mcu_budget(stm32_build: Path) -> None:
    """The firmware image's goals: <= 48 KB flash (issue 24; 64 KB in issue 7), <= 32 KB RAM (stack included)."""
    from harness.bench.qemu import size_figures
    size = size_figures(stm32_build)
    assert size["sections"][".isr_vector"] == 392                 # 16 exceptions + 82 IRQs
    assert 0 < size["components"]["network"]["flash"] < size["flash"]
    assert size["components"]["network"]["ram"] == 0             # weights stay in flash (const)
    assert size["flash"] <= 49152, f"flash {size['flash']:,} B > 48 KB (make size)"
    assert size["ram"] <= 32768, f"RAM {size['ram']:,} B > 32 KB (make size)"


# ------------------------------------------------------------------------------------------ flights
@pytest.fixture(scope="module")
def devices(probe_builds: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Host firmware and QEMU firmware, both with the probe model compiled in."""
    from harness.bench.qemu import qemu_device
    from harness.device.host import HostDevice
    log_dir = tmp_path_factory.mktemp("qemu-logs")
    host = HostDevice(probe_builds["host"], log_dir=log_dir)
    host.start()
    try:
        host.hello(timeout=5.0)
        with qemu_device(probe_builds["stm32"] / "uwb-fw.elf", log_dir) as qemu:
            yield {"host": host, "qemu": qemu}
    finally:
        host.stop()


def _flight(mode: str, duration_s: float = 2.0, seed: int = 21) -> Any:
    from harness.bench.qemu import flight_for
    return flight_for(mode, duration_s, seed)


def _fly_both(devices: dict[str, Any], flight: Any, preset: str = "outlier+nn") -> tuple[Any, Any]:
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.run_config import config_for
    from harness.stream.streamer import Pacing, Streamer

    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS[preset])
    runs = {name: Streamer(dev, timeout_s=20.0).run(flight, cfg, Pacing("windowed", 16))
            for name, dev in devices.items()}
    assert runs["qemu"].n_received == runs["host"].n_received == len(flight.uwb)
    return runs["qemu"].results, runs["host"].results


def _assert_same_estimates(q: Any, h: Any) -> None:
    from harness.stream.streamer import OUTCOME_RESULT
    assert np.all(q["outcome"] == OUTCOME_RESULT) and np.all(h["outcome"] == OUTCOME_RESULT)
    # Same decision on every measurement (accepted / which gate rejected it).
    bad = np.nonzero(q["status"] != h["status"])[0]
    assert len(bad) == 0, f"status differs at measurements {bad[:10].tolist()}"
    for key in ("px", "py", "pz"):
        diff = np.abs(q[key].astype(np.float64) - h[key].astype(np.float64))
        assert diff.max() < POS_TOL_M, f"{key}: max |qemu - host| = {diff.max():.2e} m"


def test_qemu_hello_reports_instruction_costs_and_same_model(devices: dict[str, Any],
                                                             probe_builds: dict[str, Any]) -> None:
    qh = devices["qemu"].hello(timeout=5.0)
    hh = devices["host"].hello(timeout=5.0)
    assert qh.target.rstrip(b"\x00") == b"stm32f4"
    assert int(qh.cost_unit) == 1                             # instructions
    assert int(hh.cost_unit) == 0                             # nanoseconds
    assert qh.model_hash == hh.model_hash == probe_builds["hash"]
    assert (qh.layout_twr, qh.layout_tdoa) == (hh.layout_twr, hh.layout_tdoa) == (1, 2)
    assert qh.proto_version == hh.proto_version


@pytest.mark.parametrize("mode", ["twr", "tdoa"])
def test_qemu_flight_equals_host_firmware(devices: dict[str, Any], mode: str) -> None:
    flight = _flight(mode)
    q, h = _fly_both(devices, flight)
    _assert_same_estimates(q, h)
    # The network ran on the emulated MCU (M4 kernel, FMA) and gave the host's biases (separate
    # multiply and add) within float32 rounding; its cost is in instructions.
    used = q["cost_nn"] > 0
    assert used.sum() > 0.9 * len(flight.uwb)
    assert np.all(np.abs(q["bias"][used]) > 0.0) and np.std(q["bias"][used]) > 1e-3
    assert np.max(np.abs(q["bias"].astype(np.float64) - h["bias"].astype(np.float64))) < 1e-5
    assert np.all(q["compute"][used] > q["cost_nn"][used])
    assert np.all(q["cost_update"][q["status"] == 0] > 0)


def test_qemu_costs_are_deterministic(devices: dict[str, Any]) -> None:
    """Under -icount every stage costs the same instructions when the same data is replayed."""
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.run_config import config_for
    from harness.stream.streamer import Pacing, Streamer

    flight = _flight("tdoa", duration_s=1.0)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    streamer = Streamer(devices["qemu"], timeout_s=20.0)
    a = streamer.run(flight, cfg, Pacing("windowed", 16)).results
    b = streamer.run(flight, cfg, Pacing("lockstep")).results
    assert np.all(a["cost_nn"] > 0)
    for key in ("cost_nn", "cost_gates", "cost_update", "cost_predict", "compute", "px", "status"):
        assert np.array_equal(a[key], b[key]), key


def test_shipped_build_equals_host_firmware(stm32_build: Path, tmp_path: Path) -> None:
    """The ELF that `make` ships (firmware_sim/models) against the host firmware with the same model."""
    from harness.bench.qemu import qemu_device
    from harness.device.host import HostDevice
    from harness.stm32_build import build_host
    host = HostDevice(build_host(tmp_path / "host"), log_dir=tmp_path)
    host.start()
    try:
        hh = host.hello(timeout=5.0)
        with qemu_device(stm32_build / "uwb-fw.elf", tmp_path) as qemu:
            qh = qemu.hello(timeout=5.0)
            assert qh.model_hash == hh.model_hash
            q, h = _fly_both({"host": host, "qemu": qemu}, _flight("tdoa", duration_s=1.0, seed=22))
    finally:
        host.stop()
    _assert_same_estimates(q, h)
    assert np.max(np.abs(q["bias"].astype(np.float64) - h["bias"].astype(np.float64))) < 1e-5


def _q15_probe() -> Any:
    """The probe model in q15, its TWR network's first-layer biases raised so no unit is ever 0 after ReLU
    inside the box: the M4 kernel's second layer then takes its dense loop (more than SPARSE_MAX_PAIRS
    nonzero pairs: all 25 here); the TDoA network's has 12-23 nonzero pairs, mostly the list."""
    from dataclasses import replace
    from harness.stm32_build import probe_model
    model = probe_model()
    net = model.twr
    assert net is not None
    lower = net.b1 + np.sum(np.minimum(net.w1 * -0.1, net.w1 * 1.1), axis=0)
    b1 = (net.b1 + np.maximum(0.0, -lower) + 0.05).astype(np.float32)
    xs = np.random.default_rng(3).uniform(0.0, 1.0, (4000, net.n_in))
    y0 = np.maximum(np.maximum(xs @ net.w1 + b1, 0.0) @ net.w2 + net.b2, 0.0) @ net.w3
    scale = 0.05 / (net.out_max - net.out_min) / float(np.std(y0))
    twr = replace(net, b1=b1, w3=(net.w3 * scale).astype(np.float32), b3=0.5 - float(np.mean(y0)) * scale)
    return model.replace("twr", twr).quantized("q15", name="qemu-probe-q15")


@pytest.mark.slow
def test_q15_m4_kernel_dense_and_sparse_equal_the_host(arm_tools: None, tmp_path: Path) -> None:
    """A q15 network on the M4 (SMLAD kernels, the second layer dense or over the nonzero pairs) gives the
    portable C kernel's integers: the host firmware's biases, on TWR (dense) and TDoA (mostly sparse)."""
    from harness.bench.qemu import qemu_device
    from harness.device.host import HostDevice
    from harness.stm32_build import build_host_with_model, build_stm32_with_model
    model = _q15_probe()
    stm32 = build_stm32_with_model(model, ("fw",), tmp_path / "stm32")
    host = HostDevice(build_host_with_model(model, tmp_path / "host"), log_dir=tmp_path)
    host.start()
    try:
        with qemu_device(stm32 / "uwb-fw.elf", tmp_path) as qemu:
            assert qemu.hello(timeout=5.0).model_hash == host.hello(timeout=5.0).model_hash == model.hash
            for mode in ("twr", "tdoa"):
                q, h = _fly_both({"host": host, "qemu": qemu}, _flight(mode, duration_s=1.0, seed=23))
                _assert_same_estimates(q, h)
                used = q["cost_nn"] > 0
                assert used.sum() > 0.9 * len(q) and np.std(q["bias"][used]) > 1e-3, mode
                # Same integers; the features come from each build's EKF state (its libm's sinf/cosf):
                # equal here to the bit, within 1e-5 m anywhere (as the shipped build's test).
                assert np.max(np.abs(q["bias"].astype(np.float64) - h["bias"].astype(np.float64))) < 1e-5, mode
    finally:
        host.stop()


def test_m4_network_kernels_match_pytorch_and_are_faster(stm32_build: Path, probe_builds: dict[str, Any],
                                                         tmp_path: Path) -> None:
    from harness.bench.qemu_nn import NN_TOLERANCE, network_kernels
    probe = network_kernels(n_inputs=25, seed=5, log_dir=tmp_path, elf=probe_builds["stm32"] / "uwb-nnbench.elf",
                            model="probe")
    assert {r.kind for r in probe} == {"twr", "tdoa"}
    for r in probe:
        # Every output is a real network output (not clamped, not constant), within 1e-5 of PyTorch.
        assert r.unclamped == 1.0 and r.ref_std > 0.01, r
        assert r.max_err_torch <= NN_TOLERANCE, r
    for kind in ("twr", "tdoa"):
        ladder = [r for r in probe if r.kind == kind]
        assert [r.kernel for r in ladder] == ["portable (core bias_nn.c)", "C blocked (nn_m4.c)",
                                              "asm VLDM+VFMA (nn_m4_kernel.S)"]
        assert ladder[0].instructions > ladder[1].instructions > ladder[2].instructions, ladder
        assert ladder[2].speedup > 3.0, ladder
    shipped = network_kernels(n_inputs=10, seed=6, log_dir=tmp_path, model="shipped")
    for r in shipped:
        assert r.max_err_torch <= NN_TOLERANCE, r
    # The assembly kernel has no data-dependent branch: the same shapes cost the same instructions.
    asm = {(r.model, r.kind): (r.n_in, r.instructions) for r in probe + shipped if r.kernel.startswith("asm")}
    for kind in ("twr", "tdoa"):
        if ("shipped", kind) in asm and asm[("shipped", kind)][0] == asm[("probe", kind)][0]:
            assert asm[("shipped", kind)] == asm[("probe", kind)]


def test_serial_over_a_socket_starts_without_the_pty_settle(stm32_build: Path, tmp_path: Path) -> None:
    """The default transport is a unix socket; the pty recipe (1.2 s settle) still works and answers alike."""
    from harness.device.qemu import QemuDevice, QemuOptions
    from harness.device.registry import DeviceSpec, open_device
    times: dict[str, float] = {}
    hellos = {}
    for serial in ("socket", "pty"):
        device = QemuDevice(stm32_build / "uwb-fw.elf", log_dir=tmp_path, options=QemuOptions(serial=serial))
        t0 = time.monotonic()
        device.start()
        try:
            hellos[serial] = device.hello(timeout=5.0)
            times[serial] = time.monotonic() - t0
            assert device.link.name.startswith(f"qemu-{serial}:")
        finally:
            device.stop()
    same = ("proto_version", "fw_major", "fw_minor", "fw_patch", "build_id", "model_hash", "target", "cost_unit")
    assert [getattr(hellos["socket"], k) for k in same] == [getattr(hellos["pty"], k) for k in same]
    assert times["pty"] >= QemuOptions().settle_s and times["socket"] < times["pty"]
    # --firmware selects the ELF through the session layer too
    with open_device(DeviceSpec(target="qemu", firmware=stm32_build / "uwb-fw.elf", log_dir=tmp_path)) as dev:
        assert dev.link.name.startswith("qemu-socket:")  # type: ignore[attr-defined]


def test_bench_without_its_builds_says_what_is_missing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`python -m harness.bench.qemu --no-build` before anything is built: exit 2 naming the ELFs, no traceback."""
    from harness.bench.qemu import main
    empty = str(tmp_path)
    rc = main(["--no-build", "--build-dir", empty, "--portable-build-dir", empty, "--probe-build-dir", empty])
    assert rc == 2
    err = capsys.readouterr().err
    assert "not built" in err and f"{empty}/uwb-fw.elf" in err and f"{empty}/uwb-nnbench.elf" in err
