"""Distilled ensemble against the shipped recipe, seed by seed, on the held-out recorded data.

    python scripts/distill_probe.py --set util|rcv [--seeds 0 1 2] [--teachers 4] [--jitter 0] [--out DIR]

For every seed S: the shipped recipe of `uwb-hil models` (batch 512, patience 12, <= 300 epochs, validation
on whole flights drawn by S) and the distillation of harness/biasnet/distill.py with the same seed, both
trained on the training recordings (UTIL const1/const2 trials 1-4, rcv_twr sequences 1-4) and judged on the
held-out ones (trial 5, sequence 5) with the code of `uwb-hil eval-bias` (workflow.compare, baselines
fitted on the training recordings); the teacher (the mean of the K networks) on the same samples. The
models are written to DIR (SET_recipe_S.npz, SET_distilled_kK_jJ_S.npz) so `uwb-hil eval-bias --model ...` reproduces
each figure. Prints one JSON line per (seed, held-out set).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from harness.biasnet.ceiling import fast_part
from harness.biasnet.dataset import build_samples
from harness.biasnet.distill import DistillConfig, distill
from harness.biasnet.evaluate import evaluate
from harness.biasnet.network import BiasModel
from harness.biasnet.recipes import (load_recordings, rcv_heldout_dirs, rcv_train_dirs, util_heldout_files,
                                     util_train_files)
from harness.biasnet.train import TrainConfig, train_network
from harness.biasnet.workflow import compare
from harness.paths import SHARED_DATA
from harness.twin.features import LAYOUT_TDOA_POS, LAYOUT_TWR_POSE


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", choices=("util", "rcv"), required=True)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--teachers", type=int, default=4)
    ap.add_argument("--jitter", type=float, default=0.0)
    ap.add_argument("--copies", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("out/distill"))
    args = ap.parse_args()
    util = args.set == "util"
    kind, layout = ("tdoa", LAYOUT_TDOA_POS) if util else ("twr", LAYOUT_TWR_POSE)
    train_f = load_recordings(util_train_files(args.data) if util else rcv_train_dirs(args.data))
    tests = util_heldout_files(args.data) if util else rcv_heldout_dirs(args.data)
    samples = build_samples(train_f, layout)
    args.out.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        cfg = TrainConfig(max_epochs=300, patience=12, batch_size=512, seed=seed)  # shipped.py's recorded recipe
        plain, plain_rep = train_network(samples, cfg)
        student, teacher, rep = distill(samples, cfg, DistillConfig(args.teachers, args.jitter, args.copies))
        models = {"recipe": BiasModel(**{kind: plain}, name=f"recipe_{seed}"),  # type: ignore[arg-type]
                  "distilled": BiasModel(**{kind: student}, name=f"distilled_{seed}")}  # type: ignore[arg-type]
        for name, m in models.items():
            tag = f"_k{args.teachers}_j{args.jitter:g}" if name == "distilled" else ""
            m.save(args.out / f"{args.set}_{name}{tag}_{seed}.npz")
        for path in tests:
            test = load_recordings([path])
            row = {"set": args.set, "seed": seed, "heldout": path.name, "teachers": args.teachers,
                   "jitter": args.jitter, "folds": rep.folds,
                   "teacher_best_epochs": [t.best_epoch for t in rep.teachers],
                   "student_epochs": rep.student.epochs if rep.student else None,
                   "student_vs_teacher_m": rep.student_vs_teacher_m, "recipe_best_epoch": plain_rep.best_epoch}
            for name, m in models.items():
                res = compare(m, test, train_f)
                row[name] = {"hash": m.hash_hex, **{k: res["methods"]["network"][k] for k in
                             ("rmse_corrected", "reduction", "share_of_ceiling", "share_of_ceiling_unbiased")}}
                row["raw"], row["baselines"] = res["rmse_raw"], {
                    b: {k: res["methods"][b][k] for k in ("rmse_corrected", "reduction", "share_of_ceiling",
                                                          "share_of_ceiling_unbiased")}
                    for b in ("pair-constant", "voxel-table")}
            ts = build_samples(test, layout)
            ev = evaluate("teacher", ts, lambda s: teacher.predict_batch(s.x), fast=fast_part(ts)).overall
            row["teacher"] = {"rmse_corrected": ev.rmse_corrected, "reduction": ev.reduction,
                              "share_of_ceiling": ev.share_of_ceiling,
                              "share_of_ceiling_unbiased": ev.share_of_ceiling_unbiased}
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
