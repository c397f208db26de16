"""Run-time estimates of a campaign's flights, and shards dealt by them.

A flight (its runs share one flight build and one device) costs its set-up plus each run's replay time:
a real-time run lasts the flight's own duration, a windowed or lockstep run about a fixed time per
measurement (what the host build needs per round trip, measured on this machine; the figure only needs
to be right relative to the others, the shards are balanced against each other). Shards take the flights
longest first, each to the least loaded shard (LPT), ties to the lower shard and plan order: the split
depends only on the plan, and one real-time latency flight no longer lands in the same shard as the next.
The same order (costliest first) is the order in which the local pool and the cluster start the flights,
so a long flight does not start last and leave the others idle.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from harness.campaign.plan import ROLE_RADIO, FlightSpec, PlanError, RunSpec, group_by_flight

#: per flight: worker start, flight build, device start and HELLO [s]
GROUP_SETUP_S = 1.0
#: replay time per measurement by pacing [s] (windowed: measured 30-50 us on the host build, 2 cores)
PER_MEASUREMENT_S = {"windowed": 40e-6, "lockstep": 120e-6}
#: simulated measurement rates (harness/flight/scenarios.py defaults)
SIM_RATE_HZ = {"twr": 200.0, "tdoa": 400.0}
#: a radio-level run streams packets through the TDoA engine: about twice the work of its differences
RADIO_FACTOR = 2.0


@lru_cache(maxsize=64)
def _recording_size(path: str, anchors: str | None) -> tuple[int, float]:
    """(measurements, duration [s]) of a recording, read once per process (0, 0 when unreadable: the worker
    reports that run as failed, its cost does not matter)."""
    from harness.flight.loaders import load_recording
    try:
        flight = load_recording(Path(path), anchors=Path(anchors) if anchors else None)
    except Exception:  # noqa: BLE001 - an unreadable recording fails its run in the worker, with the reason
        return 0, 0.0
    return len(flight.uwb), float(flight.duration_s)


def flight_size(spec: FlightSpec) -> tuple[int, float]:
    """Estimated (measurements, duration [s]) of a flight."""
    if spec.source == "sim":
        duration = float(spec.duration_s or 70.0)
        return int(duration * SIM_RATE_HZ.get(spec.mode, 400.0)), duration
    if spec.path is None:
        return 0, 0.0
    return _recording_size(spec.path, spec.anchors)


def run_cost_s(run: RunSpec) -> float:
    """Estimated wall time of one run on the host build [s]."""
    n, duration = flight_size(run.flight)
    cost = duration if run.pacing == "realtime" else n * PER_MEASUREMENT_S.get(run.pacing, 40e-6)
    return cost * (RADIO_FACTOR if run.role == ROLE_RADIO else 1.0)


def group_cost_s(group: list[RunSpec]) -> float:
    """Estimated wall time of one flight's runs (one worker, one device) [s]."""
    return GROUP_SETUP_S + sum(run_cost_s(r) for r in group)


def costliest_first(groups: list[list[RunSpec]]) -> list[list[RunSpec]]:
    """The groups by estimated cost, longest first (stable: equal costs keep plan order)."""
    costs = [group_cost_s(g) for g in groups]
    order = sorted(range(len(groups)), key=lambda i: -costs[i])
    return [groups[i] for i in order]


def deal(groups: list[list[RunSpec]], count: int) -> list[list[int]]:
    """Indices of `groups` per shard: longest first, each to the least loaded shard (LPT)."""
    costs = [group_cost_s(g) for g in groups]
    loads = [0.0] * count
    shards: list[list[int]] = [[] for _ in range(count)]
    for i in sorted(range(len(groups)), key=lambda j: -costs[j]):
        k = min(range(count), key=lambda s: (loads[s], s))
        shards[k].append(i)
        loads[k] += costs[i]
    return [sorted(s) for s in shards]


def shard_runs(runs: list[RunSpec], index: int, count: int) -> list[RunSpec]:
    """Shard K of N (1-based): the flights (runs sharing a flight and firmware) dealt by estimated run time,
    so every run lands in exactly one shard, the shards take about as long, and the split depends only on
    the plan."""
    if not 1 <= index <= count:
        raise PlanError(f"shard {index}/{count}: need 1 <= K <= N")
    groups = group_by_flight(runs)
    mine = deal(groups, count)[index - 1]
    return [r for i in mine for r in groups[i]]

