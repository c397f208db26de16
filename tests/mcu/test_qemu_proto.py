"""uwb-protobench.elf under QEMU: the firmware's protocol path (block receiver, in-place frame encoder) gives back
the messages it was fed and costs fewer guest instructions per frame than the byte-wise / two-copy path."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.bench.qemu_nn import BenchError
from harness.bench.qemu_proto import parse, report, run

pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="module")
def protobench(arm_tools: None) -> Path:
    from harness.stm32_build import build_stm32
    return build_stm32(("protobench",)) / "uwb-protobench.elf"


def test_block_path_is_cheaper_per_frame(protobench: Path) -> None:
    by = {(r.path, r.message): r.instructions for r in run(protobench)}
    assert set(by) == {(p, m) for p in ("rx_bytes", "rx_block") for m in ("imu", "tdoa")} | {
        ("tx_copy", "result"), ("tx_frame", "result")}
    # Receiving an IMU frame (41 bytes, ~950 per flight second): under 700 instructions, a third of byte-wise.
    assert by[("rx_block", "imu")] < 700
    assert by[("rx_block", "imu")] * 2.5 < by[("rx_bytes", "imu")]
    assert by[("rx_block", "tdoa")] < by[("rx_bytes", "tdoa")]
    assert by[("tx_frame", "result")] < by[("tx_copy", "result")]
    assert by == {(r.path, r.message): r.instructions for r in run(protobench)}  # exact: same every run


def test_parse_refuses_failures_and_truncation() -> None:
    rows = parse("rx_bytes imu 1500\nrx_block imu 500\nok\n")
    assert [(r.path, r.message, r.instructions) for r in rows] == [("rx_bytes", "imu", 1500), ("rx_block", "imu", 500)]
    assert "3.00x" in report(rows)[1]
    with pytest.raises(BenchError, match="did not give back"):
        parse("rx_bytes imu 1500\nFAIL rx_block 0\nok\n")
    with pytest.raises(BenchError, match="incomplete"):
        parse("rx_bytes imu 1500\n")
