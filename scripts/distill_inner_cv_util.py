"""The UTIL side of distill_inner_cv.py: is distillation better than one network WITHOUT trial 5?

    python scripts/distill_inner_cv_util.py [--seeds 0] [--trials 1 2 3 4]

For every training trial j of 1-4: train on the const1/const2 flights of the other three trials (one network,
and the distilled recipe with one teacher per trial group), and judge on trial j's flights (const1 tdoa2,
const1 tdoa3, const2 tdoa2) against the voxel table fitted on the same three trials. Trial 5 is never
loaded. Prints the measurement-error cut of each method per left-out set and the mean gain over the voxel
table. Slow: ~4 networks per fold (minutes each on 2 cores).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

from harness.biasnet.baselines import VoxelTable
from harness.biasnet.dataset import build_samples
from harness.biasnet.distill import DistillConfig, distill
from harness.biasnet.recipes import load_recordings, util_files
from harness.biasnet.train import TrainConfig, train_network
from harness.paths import SHARED_DATA
from harness.twin.features import LAYOUT_TDOA_POS


def _cut(raw: np.ndarray, corrected: np.ndarray) -> float:
    return 100.0 * (1.0 - float(np.sqrt(np.mean(corrected ** 2)) / np.sqrt(np.mean(raw ** 2))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--trials", type=int, nargs="+", default=[1, 2, 3, 4])
    args = ap.parse_args()
    if not set(args.trials) <= {1, 2, 3, 4}:
        ap.error("--trials must be among 1-4 (trial 5 is the held-out set)")
    gains: dict[str, list[float]] = {"one": [], "distilled": []}
    for seed in args.seeds:
        for j in args.trials:
            others = tuple(t for t in (1, 2, 3, 4) if t != j)
            train = build_samples(load_recordings(util_files(args.data, others)), LAYOUT_TDOA_POS)
            cfg = TrainConfig(max_epochs=300, patience=12, batch_size=512, seed=seed)
            one = train_network(train, cfg)[0]
            dist = distill(train, cfg, DistillConfig(teachers=len(others)))[0]
            voxel = VoxelTable().fit(train)
            for path in util_files(args.data, (j,)):
                te = build_samples(load_recordings([path]), LAYOUT_TDOA_POS)
                v = _cut(te.bias, te.bias - voxel.predict(te))
                o = _cut(te.bias, te.bias - one.predict_batch(te.x))
                d = _cut(te.bias, te.bias - dist.predict_batch(te.x))
                gains["one"].append(o - v)
                gains["distilled"].append(d - v)
                print(f"seed {seed} trial {j} {path.name}: voxel {v:.1f} %, one network {o:.1f} %, "
                      f"distilled {d:.1f} %", flush=True)
    for k, g in gains.items():
        print(f"{k}: mean gain over the voxel table {statistics.mean(g):+.2f} points, worst {min(g):+.2f}")


if __name__ == "__main__":
    main()
