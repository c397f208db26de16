"""`uwb-hil demo`: TWR and TDoA flights in three configurations, then TDoA at LPS radio level (TDoA2, TDoA3),
all through one device."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from harness.flight.data import Flight
from harness.report.summarize import summarize_run
from harness.device.registry import DeviceSpec, open_device
from harness.flight.run_config import run_estimator_config
from harness.stream.streamer import Pacing, Streamer

#: (mode, configurations) of the measurement-level flights, and the configurations of the radio-level ones
DEMO_MODES = (("twr", ("none", "outlier", "outlier+nn")), ("tdoa", ("none", "outlier", "outlier+nn")))
RADIO_PROTOCOLS = ("tdoa2", "tdoa3")
RADIO_PRESETS = ("outlier", "outlier+nn")


@dataclass(frozen=True)
class DemoFlights:
    """The simulated flights of the demo (the same scenario and seed for every mode)."""
    scenario: str = "circle"
    duration_s: float = 20.0
    seed: int = 1


def run_demo(spec: DeviceSpec, flights: DemoFlights, pacing: Pacing,
             timeout_s: float) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Fly every demo row through one device. Returns the device identity and one summary per row (with
    `mode` and `config`; radio rows also with their radio section)."""
    from harness.flight.radio import radio_level
    from harness.flight.scenarios import scenario_flight
    rows = []
    with open_device(spec) as device:
        ident = device.identity
        connection = device.connection()
        streamer = Streamer(device, timeout_s=timeout_s)

        def fly(flight: Flight, preset: str, mode: str, radio: bool = False) -> dict[str, Any]:
            cfg = run_estimator_config(flight, preset)
            run = streamer.run(flight, cfg, pacing, radio=radio)
            s = summarize_run(run, flight, ident, config=preset, radio_streamer=streamer if radio else None,
                              connection=connection)
            s["mode"] = mode
            return s

        for mode, presets in DEMO_MODES:
            flight = scenario_flight(flights.scenario, mode=mode, duration_s=flights.duration_s, seed=flights.seed)
            rows += [fly(flight, preset, mode) for preset in presets]
        # Radio level: the tag's engine turns anchor packets into the TDoA measurements (one per packet).
        base = scenario_flight(flights.scenario, mode="tdoa", duration_s=flights.duration_s, seed=flights.seed)
        for protocol in RADIO_PROTOCOLS:
            flight = radio_level(base, protocol, seed=flights.seed)
            rows += [fly(flight, preset, f"{protocol} radio", radio=True) for preset in RADIO_PRESETS]
    return {**ident.as_dict(), **connection}, rows
