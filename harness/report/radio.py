"""The `radio` section of a run summary: packets, measurements formed, drops by reason, and the
engine's clock-skew estimate per anchor against the simulator's truth."""

from __future__ import annotations

from typing import Any

import numpy as np

from harness.flight.data import Flight
from harness.stream.results_file import OUTCOME_ERROR, OUTCOME_LOST, OUTCOME_NO_MEAS, OUTCOME_RESULT
from harness.stream.streamer import RunResult, Streamer
from protocol import messages as m
from protocol._generated import DropReason


def radio_senders(flight: Flight) -> list[int]:
    if flight.radio is None:
        return []
    return sorted({int(v) & 0xFF for v in np.unique(flight.radio.src_addr)})


def query_clocks(streamer: Streamer, flight: Flight) -> dict[int, m.Clock]:
    """Ask the device for its clock correction of every anchor the flight's packets came from."""
    return {a: streamer.channel.clock(a, streamer.timeout_s) for a in radio_senders(flight)}


def radio_summary(run: RunResult, flight: Flight, clocks: dict[int, m.Clock]) -> dict[str, Any]:
    res = run.results
    out = res["outcome"]
    drops = {r.name.lower(): int(np.count_nonzero((out == OUTCOME_NO_MEAS) & (res["error_code"] == int(r))))
             for r in DropReason}
    truth = flight.radio.true_skew_ppm if flight.radio is not None else {}
    per_anchor: dict[str, Any] = {}
    errors = []
    for a, c in clocks.items():
        entry: dict[str, Any] = {"known": bool(c.known), "bucket": int(c.bucket), "skew_ppm": float(c.skew_ppm),
                                 "packets": int(c.packets)}
        if a in truth and c.known:
            entry["true_skew_ppm"] = truth[a]
            entry["skew_error_ppm"] = float(c.skew_ppm) - truth[a]
            errors.append(abs(entry["skew_error_ppm"]))
        per_anchor[str(a)] = entry
    stats = run.stats
    return {
        "protocol": flight.radio.protocol if flight.radio is not None else None,
        "packets": int(len(res)),
        "measurements": int(np.count_nonzero(out == OUTCOME_RESULT) + np.count_nonzero(out == OUTCOME_ERROR)),
        "no_measurement": int(np.count_nonzero(out == OUTCOME_NO_MEAS)),
        "lost": int(np.count_nonzero(out == OUTCOME_LOST)),
        "drops": drops,
        "device_counters": {k: getattr(stats, k) for k in ("radio_packets", "radio_meas", "radio_no_reference",
                                                            "radio_clock", "radio_expired", "radio_malformed",
                                                            "radio_unknown_type", "radio_no_position", "baseline_rejects")}
        if stats is not None else None,
        "clock": per_anchor,
        "max_skew_error_ppm": max(errors) if errors else None,
    }


def format_radio(r: dict[str, Any]) -> str:
    drops = ", ".join(f"{k} {v}" for k, v in r["drops"].items() if v)
    skew = r["max_skew_error_ppm"]
    return (f"  radio {r['protocol']}: {r['packets']} packets -> {r['measurements']} measurements, "
            f"{r['no_measurement']} without ({drops or 'none'}); clock skew error max "
            f"{'-' if skew is None else f'{skew:.4f}'} ppm over {len(r['clock'])} anchors")
