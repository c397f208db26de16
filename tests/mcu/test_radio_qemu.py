"""The radio level on the STM32F405 under QEMU: the engine forms the same measurements as its twin, and
one TDoA3 packet through engine + network + update stays within 25,000 instructions."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="module")
def stm32_elf(arm_tools: None) -> Path:
    from harness.stm32_build import build_stm32
    return build_stm32(("fw",)) / "uwb-fw.elf"


def test_tdoa3_packet_cost_and_twin_on_qemu(stm32_elf: Path) -> None:
    from harness.bench.qemu import qemu_device
    from harness.bench.radio import GOAL_RADIO_TDOA3_INSTR, radio_stage
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.radio import radio_level
    from harness.flight.scenarios import scenario_flight
    from harness.flight.run_config import config_for
    from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer
    from harness.twin.tdoa_engine import MEASUREMENT, replay

    with qemu_device(stm32_elf) as dev:
        row = radio_stage(dev, 2.0, 5)
        assert row.n > 100 and row.compute <= GOAL_RADIO_TDOA3_INSTR
        assert row.compute > row.nn + row.update   # the engine's share is in it
        flight = radio_level(scenario_flight("circle", mode="tdoa", duration_s=2.0, seed=6), "tdoa2", seed=6, loss=0.2)
        cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
        run = Streamer(dev, timeout_s=20.0).run(flight, cfg, Pacing("windowed", 16), radio=True)
    r = flight.radio
    assert r is not None
    _, twin = replay(r.t_us.tolist(), [int(v) for v in r.rx_ts], [int(v) for v in r.src_addr],
                     [bytes(r.payload[k, :int(r.length[k])]) for k in range(len(r))])
    assert (run.results["outcome"] == OUTCOME_RESULT).tolist() == [rc == MEASUREMENT for rc, _ in twin]
