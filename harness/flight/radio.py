"""A flight at LPS radio level: simulated flights through the radio simulator (its error model at
timestamp level), recorded TDoA flights through the packet synthesis of radio_replay."""

from __future__ import annotations

from harness.errors import UsageError
from harness.flight.measurement_errors import sim_config
from harness.flight.data import Flight
from harness.flight.radio_replay import RadioReplayError, radio_from_recording
from harness.flight.radio_sim import PROTOCOLS, RadioConfig, simulate_radio


def radio_level(flight: Flight, protocol: str, seed: int = 1, loss: float = 0.0) -> Flight:
    """The flight with its radio stream (`Flight.radio`) and, for a simulated flight, the matching
    measurement-level stream in `uwb` (same pairs, times and link errors)."""
    if protocol not in PROTOCOLS:
        raise UsageError(f"--radio must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    if flight.meta.get("source") == "simulator":
        noise = flight.meta.get("noise")
        if noise == "gaussian":
            raise UsageError("radio level simulates the realistic error model (or none), not gaussian noise")
        sim = sim_config(str(flight.meta.get("profile", "los"))) if noise == "realistic" else None
        return simulate_radio(flight, RadioConfig(protocol=protocol, seed=seed, loss=loss), sim)
    if loss:
        raise RadioReplayError("--radio-loss applies to simulated flights; a recording replays its own measurements")
    return radio_from_recording(flight, protocol)
