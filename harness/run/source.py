"""The flight and estimator configuration of one run: built from a RunSource, the options that decide them.

The RunSource is also what a results file's header records (`source`), so that `run --resume` rebuilds the
very same flight and configuration from the file alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

from harness.config import EstimatorConfig
from harness.errors import UsageError
from harness.flight.data import Flight
from harness.flight.run_config import run_estimator_config
from harness.report.phases import DEFAULT_FLIGHT_ABOVE_M


@dataclass(frozen=True)
class RunSource:
    """A simulated or recorded flight, its radio level and planar mode, and the estimator options."""
    scenario: str = "circle"
    mode: str = "twr"
    duration: float = 30.0
    seed: int = 1
    recording: str | None = None
    anchors: str | None = None
    constellation: int | None = None
    force: bool = False
    stages: str = "outlier+nn"
    uwb_only: bool = False
    model: str | None = None
    set: Sequence[str] = field(default_factory=list)
    radio: str | None = None
    radio_loss: float = 0.0
    radio_trace: str | None = None      # recorded anchor packets (harness/flight/radio_trace.py)
    height: str | None = None
    height_std: float = 0.05
    range_offset: str | None = None     # a range-offset calibration file (harness/flight/range_offset.py)
    ignore_crc: bool = False            # Crazyflie uSD logs: load despite a CRC mismatch
    lever_arm: Sequence[float] | str | None = None   # uSD logs: the tag's lever arm or its calibration file
    tof: bool | None = None             # uSD logs: fuse the ToF ranger (None: the default, TOF_DEFAULT)
    flight_above: float = DEFAULT_FLIGHT_ABOVE_M   # truth z [m] below which a measurement is in the ground phase

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> RunSource:
        """From parsed options or a results header: the keys of a RunSource, others ignored; a key that is
        missing or None takes the default (a header written before the key existed)."""
        given = {k: values[k] for k in cls.keys() if values.get(k) is not None}
        return cls(**given)

    def check_options_apply(self) -> None:
        """Refuse options the flight would silently ignore: those of a recording on a simulated flight (a
        --lever-arm file that does not exist ran with exit 0), --radio-loss without --radio."""
        if not self.recording:
            unused = [f"--{k.replace('_', '-')}" for k in ("anchors", "constellation", "lever_arm", "tof")
                      if getattr(self, k) is not None] + (["--ignore-crc"] if self.ignore_crc else [])
            if unused:
                raise UsageError(f"{', '.join(unused)} appl{'y' if len(unused) > 1 else 'ies'} to a recorded "
                                 "flight (--recording): a simulated flight has its own anchors and tag")
        if self.radio_loss and not self.radio:
            raise UsageError("--radio-loss is the tag's packet loss at radio level: it needs --radio")

    def as_header(self) -> dict[str, Any]:
        """For the results header: file paths made absolute, so a resume works from any directory."""
        src = asdict(self)
        # a settings file (`--set @FILE.toml`) too; the resume re-reads it (its values are not in the header,
        # but the resume compares the configuration they give with the recorded run's)
        src["set"] = [f"@{Path(item[1:]).resolve()}" if item.startswith("@") else item for item in self.set]
        for k in ("recording", "anchors", "model", "range_offset", "radio_trace"):
            if src[k]:
                src[k] = str(Path(src[k]).resolve())
        if isinstance(self.lever_arm, str):      # a calibration file (`uwb-hil lever-arm`)
            src["lever_arm"] = str(Path(self.lever_arm).resolve())
        return src


def make_flight(src: RunSource) -> Flight:
    """The flight (measurement level): its ranges calibrated when `range_offset` is given, with HEIGHT
    pseudo-measurements when `height` is given."""
    if src.recording:
        from harness.flight.formats.cf_usd_flight import TOF_DEFAULT
        from harness.flight.loaders import UsdOptions, load_recording
        tof = TOF_DEFAULT if src.tof is None else src.tof
        flight = load_recording(Path(src.recording), anchors=Path(src.anchors) if src.anchors else None,
                                constellation=src.constellation, check=not src.force,
                                usd=UsdOptions.make(src.ignore_crc, src.lever_arm, tof))
    else:
        from harness.flight.scenarios import scenario_flight
        flight = scenario_flight(src.scenario, mode=src.mode, duration_s=src.duration, seed=src.seed)
    if src.range_offset:
        from harness.flight.range_offset import apply_range_offset, load_range_offset
        flight = apply_range_offset(flight, load_range_offset(Path(src.range_offset)))
    if not src.height:
        return flight
    from harness.flight.planar import parse_height, with_height
    return with_height(flight, parse_height(str(src.height)), float(src.height_std))


def make_run_flight(src: RunSource) -> Flight:
    """make_flight, at LPS radio level when `radio` names a protocol."""
    if (src.radio or src.radio_trace) and not src.recording and src.mode != "tdoa":
        raise UsageError("--radio / --radio-trace stream TDoA anchor packets: use them with --mode tdoa "
                         "(or a TDoA recording)")
    if src.radio and src.radio_trace:
        raise UsageError("--radio simulates the anchor packets, --radio-trace replays recorded ones: one of them")
    flight = make_flight(src)
    if src.radio_trace:
        from harness.flight.radio_trace import attach_trace, load_radio_trace
        return attach_trace(flight, load_radio_trace(src.radio_trace))
    if not src.radio:
        return flight
    from harness.flight.radio import radio_level
    return radio_level(flight, src.radio, seed=src.seed, loss=src.radio_loss)


def long_simulation(src: RunSource) -> Any:
    """The SimPlan of a simulated flight long enough to be streamed in slices, else None."""
    from harness.stream.chunked_run import STREAM_ABOVE_S
    if src.recording or src.range_offset or src.duration <= STREAM_ABOVE_S:
        return None
    from harness.flight.scenarios import plan_scenario
    return plan_scenario(src.scenario, mode=src.mode, duration_s=src.duration, seed=src.seed)


def source_config(src: RunSource, flight: Flight) -> EstimatorConfig:
    """The estimator configuration of a run (a resume checks the recorded one against it: whatever changes
    it must be a RunSource field)."""
    return run_estimator_config(flight, src.stages, src.set, uwb_only=src.uwb_only)


