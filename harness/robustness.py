"""Figures for docs/robustness.md: a flight through the host firmware over a FaultyLink, and what the device,
the link's shadow parser and the run's results say was injected, rejected and lost.

    python -m harness.robustness --seconds 60 --seed 21        # tx faults, then rx faults
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from typing import Any, Sequence

import numpy as np

from harness.config import PRESETS, EstimatorConfig
from harness.device.registry import DeviceSpec, open_device
from harness.errors import report_failure
from harness.flight.scenarios import scenario_flight
from harness.link.faulty import FaultRates, FaultyLink, unwrap_seqs
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE
from harness.stream.results_file import OUTCOME_LOST, OUTCOME_RESULT
from harness.stream.streamer import Pacing, Streamer
from protocol import messages as m

TX_RATES = FaultRates(bit_flip=2e-4, drop_byte=2e-4, drop_frame=0.01, duplicate_frame=0.01, truncate_frame=0.005,
                      garbage=0.005, garbage_max=40, stall=0.001, stall_s=0.02)
RX_RATES = FaultRates(bit_flip=3e-4, drop_byte=1e-4, drop_frame=0.01, truncate_frame=0.005, garbage=0.005,
                      stall=0.001, stall_s=0.02)


def fault_accounting(seconds: float, seed: int, direction: str) -> dict[str, Any]:
    """One faulted run on a fresh host build; the accounting from all three sides."""
    flight = scenario_flight("circle", mode="twr", duration_s=seconds, seed=seed, noise="gaussian", noise_std=0.05)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
    tx, rx = (TX_RATES, FaultRates()) if direction == "tx" else (FaultRates(), RX_RATES)
    with open_device(DeviceSpec(timeout_s=10.0)) as dev:
        s0 = dev.channel.stats(timeout=2.0)
        link = FaultyLink(dev.link, tx=tx, rx=rx, seed=seed)
        with dev.channel.through(link) as channel:     # same session (seqs go on), faulty transport
            run = Streamer(channel, timeout_s=1.0).run(flight, cfg, Pacing("windowed", 32))
    assert run.stats is not None
    d = {k: getattr(run.stats, k) - getattr(s0, k) for k, _ in m.Stats.FIELDS}
    log = link.tx_log if direction == "tx" else link.rx_log
    res = run.results
    meas_key = unwrap_seqs(res["meas_seq"])
    meas = set(meas_key.tolist())
    lost = log.lost_seqs & meas if direction == "tx" else log.lost_seqs
    lost_rows = set(meas_key[res["outcome"] == OUTCOME_LOST].tolist())
    ok = res["outcome"] == OUTCOME_RESULT
    finite = bool(np.all(np.isfinite(np.stack([res["px"][ok], res["py"][ok], res["pz"][ok]]))))
    out: dict[str, Any] = {"direction": direction, "seconds": seconds, "seed": seed,
                           "measurements": len(res), "injected": dict(log.counts)}
    if direction == "tx":
        out["device"] = {k: d[k] for k in ("frames_ok", "crc_errors", "framing_errors", "seq_gaps", "twr_meas",
                                           "results")}
    else:
        out["host_decoder"] = asdict(run.decoder_errors)
    out["link_shadow"] = {"delivered_ok": log.delivered.frames_ok, "crc_errors": log.delivered.errors.crc_errors,
                          "framing_errors": log.delivered.errors.framing_errors,
                          "frames_lost": len(log.lost_seqs)}
    out["results"] = {"result": int(ok.sum()), "lost": len(lost_rows), "measurements_lost_on_link": len(lost)}
    if direction == "tx":
        agree = (d["crc_errors"] == log.delivered.errors.crc_errors
                 and d["framing_errors"] == log.delivered.errors.framing_errors
                 and d["frames_ok"] == log.delivered.frames_ok and d["seq_gaps"] == len(log.lost_seqs))
    else:
        agree = (run.decoder_errors.crc_errors == log.delivered.errors.crc_errors
                 and run.decoder_errors.framing_errors == log.delivered.errors.framing_errors)
    out["agree"] = bool(agree and lost_rows == lost)
    out["estimate_finite"] = finite
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.robustness", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=21)
    args = ap.parse_args(argv)
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        print(f"robustness: error: --seconds must be a positive number, got {args.seconds}", file=sys.stderr)
        return 2
    if not DEFAULT_FIRMWARE.exists():
        print(f"{DEFAULT_FIRMWARE} not built: run `make firmware`", file=sys.stderr)
        return 2
    ok = True
    try:
        for direction in ("tx", "rx"):
            fig = fault_accounting(args.seconds, args.seed, direction)
            print(json.dumps(fig))
            ok &= fig["agree"] and fig["estimate_finite"]
    except Exception as exc:  # noqa: BLE001 - exit 1 means "the accounting disagrees": never for an error
        return report_failure(exc, "robustness")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
