"""FlightSpec: how a campaign obtains one flight (its own module: the plan and the recorded sections both
need it, harness/campaign/plan.py and recorded_usd.py)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


@dataclass(frozen=True)
class FlightSpec:
    """How to obtain one flight. ``source`` is "sim" (scenario_flight) or "recorded" (load_recording)."""

    source: str
    mode: str                      # "twr" | "tdoa"
    trajectory: str                # scenario name, or a label of the recording
    seed: int | None = None
    duration_s: float | None = None
    path: str | None = None        # recording (file or sequence directory)
    anchors: str | None = None     # anchor file of the recording, if separate
    uwb_only: bool = False
    takeoff: bool = True           # simulated: ground wait, take-off and landing inside duration_s
    profile: str = "los"           # simulated: error-model profile of harness/flight/scenarios.py
    radio: str | None = None       # "tdoa2" | "tdoa3": the flight at LPS radio level (harness/flight/radio.py)
    lever_arm: tuple[float, float, float] | None = None  # uSD log: the tag's calibrated lever arm (None: UTIL's)
    tof: bool = False              # uSD log: its ToF ranger's readings fused too (flow deck)

    def __post_init__(self) -> None:
        # a plan read back from JSON (shards, workers) gives a list: keep the spec hashable and equal to its
        # original (runs are grouped by flight, plan.group_by_flight)
        if self.lever_arm is not None:
            x, y, z = (float(v) for v in self.lever_arm)
            object.__setattr__(self, "lever_arm", (x, y, z))

    @property
    def flight_id(self) -> str:
        radio = f"-radio-{self.radio}" if self.radio else ""
        if self.source == "sim":
            return f"sim-{self.mode}-{self.trajectory}-s{self.seed}{radio}"
        return f"rec-{self.mode}-{self.trajectory}{radio}"

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if d["radio"] is None:
            del d["radio"]       # fingerprints of measurement-level runs stay what they were before radio level
        if d["lever_arm"] is None:
            del d["lever_arm"]   # the same for every recording but the uSD logs
        if not d["tof"]:
            del d["tof"]         # the same: fingerprints of the replays without the ranger unchanged
        return d
