"""The one assembly of a run's summary on a device (`uwb-hil run`, its resumption, `demo`, a campaign run):
the metrics of report/metrics.py run_summary in the device's cost unit, the device's identity, the flight's
range offset, and for a radio-level run the radio section (asks the device for its clock estimates)."""

from __future__ import annotations

from typing import Any, Protocol

from harness.flight.data import Flight
from harness.kinds import kind_of
from harness.report.metrics import DEFAULT_BUDGET_S, run_summary
from harness.report.phases import DEFAULT_FLIGHT_ABOVE_M, add_phases
from harness.stream.streamer import RunResult, Streamer


class Identity(Protocol):
    """What a summary needs of a device's identity (device/identity.py DeviceIdentity)."""

    @property
    def cost_unit(self) -> int: ...

    def as_dict(self) -> dict[str, Any]: ...


def summarize_run(run: RunResult, flight: Flight, identity: Identity, config: str | None = None,
                  radio_streamer: Streamer | None = None,
                  connection: dict[str, Any] | None = None,
                  flight_above: float = DEFAULT_FLIGHT_ABOVE_M) -> dict[str, Any]:
    """The summary of one run (without a verdict). `config`: the preset or stages label the run was asked
    with; `radio_streamer`: the streamer of a radio-level run, still connected (its clocks are queried);
    `connection`: how the device was reached (Device.connection(): port, baud, USB serial number);
    `flight_above`: truth z [m] below which a measurement is in the ground phase (report/phases.py)."""
    summary: dict[str, Any] = run_summary(run, flight, DEFAULT_BUDGET_S, cost_unit=identity.cost_unit)
    add_phases(summary, run, flight, flight_above)
    if config is not None:
        summary["config"] = config
    summary["device"] = {**identity.as_dict(), **(connection or {})}
    if "range_offset" in flight.meta:
        summary["range_offset"] = flight.meta["range_offset"]
    if flight.aux is not None:      # fused, not scored (the ToF ranger of a Crazyflie log)
        summary["auxiliary"] = {"kind": kind_of(flight.aux.kind).key, "measurements": len(flight.aux)}
    warnings = flight.meta.get("warnings")     # the reader's (a CRC mismatch loaded with --ignore-crc, ...)
    if isinstance(warnings, list) and warnings:
        summary["warnings"] = [str(w) for w in warnings]
    if radio_streamer is not None:
        from harness.report.radio import query_clocks, radio_summary
        summary["radio"] = radio_summary(run, flight, query_clocks(radio_streamer, flight))
    return summary
