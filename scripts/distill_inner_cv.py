"""How many teachers per flight group, chosen without the held-out data: leave one TRAINING group out.

    python scripts/distill_inner_cv.py [--per-group 1 2] [--seeds 0 1 2 3]

rcv_twr only (UTIL's networks take minutes each): for every training sequence j of 1-4, distil on the other
three with G x P teachers (P per group: 1 or 2; P = 0: one network, the one-network recipe) and the
shipped recipe's settings, and judge on sequence j
against one constant fitted on the three (as the per-anchor table falls back to on a new placement), seed
by seed. Sequence 5 is never loaded. Prints one line per (P, seed) and the mean and worst ratio per P.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

from harness.biasnet.baselines import PairConstant
from harness.biasnet.dataset import build_samples
from harness.biasnet.distill import DistillConfig, distill
from harness.biasnet.recipes import load_recordings, rcv_train_dirs
from harness.biasnet.train import TrainConfig, train_network
from harness.paths import SHARED_DATA
from harness.twin.features import LAYOUT_TWR_POSE


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--per-group", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = ap.parse_args()
    flights = load_recordings(rcv_train_dirs(args.data))
    for p in args.per_group:
        ratios = []
        for seed in args.seeds:
            row = []
            for j in range(len(flights)):
                train = [f for k, f in enumerate(flights) if k != j]
                tr, te = build_samples(train, LAYOUT_TWR_POSE), build_samples([flights[j]], LAYOUT_TWR_POSE)
                cfg = TrainConfig(max_epochs=300, patience=12, batch_size=512, seed=seed)
                student = (distill(tr, cfg, DistillConfig(teachers=p * len(train)))[0] if p > 0
                           else train_network(tr, cfg)[0])
                const = PairConstant().fit(tr).predict(te)
                rmse = float(np.sqrt(np.mean((te.bias - student.predict_batch(te.x)) ** 2)))
                row.append(rmse / float(np.sqrt(np.mean((te.bias - const) ** 2))))
            ratios.append(row)
            print(f"{p} per group, seed {seed}: " + " ".join(f"{r:.2f}" for r in row) + " x the constant", flush=True)
        flat = [r for row in ratios for r in row]
        print(f"{p} per group: mean {statistics.mean(flat):.3f} x, worst {max(flat):.2f} x, "
              f"sd over seeds of the mean {statistics.pstdev([statistics.mean(r) for r in ratios]):.3f}", flush=True)


if __name__ == "__main__":
    main()
