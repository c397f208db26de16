"""Measurement level share of the ceiling of what the firmware subtracted during a replay.

    python scripts/subtracted_share.py RESULTS.jsonl RECORDING --anchors ANCHORS.csv

RESULTS.jsonl is `uwb-hil run --results` of that recording; RESULT.bias is what the firmware subtracted
from each measurement (the network's correction, plus the bias states with stage BIAS_STATES). Prints the
RMSE of the true error (measured - true, |error| < 0.7 m) before and after that, the floor (error minus
its +-0.25 s moving average per pair, harness/biasnet/ceiling.py) and the share of the ceiling, as
`uwb-hil eval-bias` does for a network alone.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from harness.biasnet.ceiling import fast_part, share_of_ceiling
from harness.biasnet.dataset import flight_samples
from harness.biasnet.recipes import load_recordings


def subtracted(results: Path, n: int) -> np.ndarray:
    """RESULT.bias by measurement index (NaN where there was no result)."""
    out = np.full(n, np.nan)
    with results.open() as f:
        for line in f:
            r = json.loads(line)
            if r.get("type") == "result" and r.get("outcome") == 1:
                out[int(r["index"])] = float(r["bias"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path)
    ap.add_argument("recording", type=Path)
    ap.add_argument("--anchors", type=Path, default=None)
    args = ap.parse_args()
    flight = load_recordings([args.recording], args.anchors)[0]
    s = flight_samples(flight)
    assert s.row is not None
    bias = subtracted(args.results, len(flight.uwb))[s.row]
    keep = np.isfinite(bias)
    s = s.subset(keep)
    raw, corr = s.bias, s.bias - bias[keep]
    part = fast_part(s)
    floor, floor_u = part.floor(), part.floor_unbiased()
    r_raw, r_corr = float(np.sqrt(np.mean(raw ** 2))), float(np.sqrt(np.mean(corr ** 2)))
    print(f"{args.recording.name}: n {len(raw)}  RMSE raw {r_raw:.4f}  after {r_corr:.4f} m "
          f"({100 * (1 - r_corr / r_raw):.1f} % cut)  floor {floor:.4f}  "
          f"share of ceiling {100 * share_of_ceiling(r_raw, r_corr, floor):.0f} %  "
          f"(unbiased floor {floor_u:.4f}: {100 * share_of_ceiling(r_raw, r_corr, floor_u):.0f} %)")


if __name__ == "__main__":
    main()
