"""`make bench` (QEMU part, radio level): one TDoA3 anchor packet through the firmware's TDoA engine,
the bias network and the EKF update, counted in guest instructions on the STM32F405 under QEMU.

RESULT.compute of a RADIO frame spans parsing, the engine, the network, the gates and the update
(app/fw_radio.c fw_on_radio); the median over packets that formed a measurement the network corrected and the
filter accepted is the figure (goal <= 25,000 instructions).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from protocol.messages import Status

GOAL_RADIO_TDOA3_INSTR = 25_000


@dataclass
class RadioRow:
    protocol: str
    packets: int
    n: int                 # packets that formed an accepted, network-corrected measurement
    compute: float         # median instructions: engine + network + gates + update
    compute_max: int
    nn: float
    update: float
    wall_s: float


def radio_stage(device: Any, duration_s: float, seed: int, protocol: str = "tdoa3") -> RadioRow:
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.radio import radio_level
    from harness.flight.scenarios import scenario_flight
    from harness.flight.run_config import config_for
    from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer

    base = scenario_flight("circle", mode="tdoa", duration_s=max(duration_s, 2.0), seed=seed)
    flight = radio_level(base, protocol, seed=seed)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    run = Streamer(device, timeout_s=20.0).run(flight, cfg, Pacing("windowed", 16), radio=True)
    res = run.results
    ok = (res["outcome"] == OUTCOME_RESULT) & (res["status"] == Status.ACCEPTED) & (res["cost_nn"] > 0)
    return RadioRow(protocol=protocol, packets=len(res), n=int(ok.sum()),
                    compute=float(np.median(res["compute"][ok])) if ok.any() else float("nan"),
                    compute_max=int(res["compute"][ok].max()) if ok.any() else 0,
                    nn=float(np.median(res["cost_nn"][ok])) if ok.any() else float("nan"),
                    update=float(np.median(res["cost_update"][ok])) if ok.any() else float("nan"),
                    wall_s=run.wall_s)


def format_row(r: dict[str, Any]) -> str:
    ok = r["compute"] <= GOAL_RADIO_TDOA3_INSTR
    return (f"{r['protocol'].upper()} packet: engine + network + update {r['compute']:,.0f} instructions (median of "
            f"{r['n']} of {r['packets']} packets; max {r['compute_max']:,}; network {r['nn']:,.0f}, update "
            f"{r['update']:,.0f}); goal <= {GOAL_RADIO_TDOA3_INSTR:,}: {'OK' if ok else 'MISSED'}")
