"""Fold networks for cross-validated filter tuning of the UTIL UWB-only replays (docs/bias-network.md,
"Filter settings, cross-validated").

    python scripts/replay_cv_folds.py [--out out/replay_cv] [--seed 0]

Trains the recorded UTIL network exactly as `make models` does (harness/biasnet/shipped.py: const1/const2
trials 1-4, distilled from RECORDED_TEACHERS networks, teacher k validated on trial k and trained on the
other three) and keeps, besides the student (the shipped network, saved as util_student.npz: its hash is
models.json's on the machine that built that), every teacher as util_fold_trialK.npz. Teacher k never
trained on trial k: replaying trial k's flights with it is an out-of-fold replay (early stopping did watch
trial k, so the figures are slightly optimistic for every filter setting alike). Trial 5 is not loaded.

    python scripts/replay_cv_folds.py --leave-out T

instead distils the recipe on the three other training trials (K = 3 teachers, each validated on one of
them) into util_fold_trialT_distilled.npz: a network that neither trained on trial T nor watched it, to
check that the teachers' out-of-fold figures rank filter settings as a fully held-out network does.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from harness.biasnet.dataset import XI_DEFAULT, build_samples
from harness.biasnet.distill import DistillConfig, distill
from harness.biasnet.network import BiasModel
from harness.biasnet.recipes import load_recordings, util_train_files
from harness.biasnet.shipped import RECORDED_TEACHERS, _train_cfg
from harness.biasnet.workflow import distill_dict
from harness.paths import SHARED_DATA
from harness.twin.features import LAYOUT_TDOA_POS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--out", type=Path, default=Path("out/replay_cv"))
    ap.add_argument("--seed", type=int, default=0, help="TrainConfig seed (make models: 0)")
    ap.add_argument("--leave-out", type=int, default=None, metavar="T", help="distil without training trial T")
    args = ap.parse_args()
    paths = util_train_files(args.data)
    if args.leave_out is not None:
        paths = [p for p in paths if f"trial{args.leave_out}-" not in p.name]
    if not paths or any("trial5" in p.name for p in paths):
        raise SystemExit(f"expected the UTIL training files (trials 1-4) under {args.data}")
    cfg = _train_cfg(quick=False, max_epochs=300)
    if args.seed:
        from dataclasses import replace
        cfg = replace(cfg, seed=args.seed)
    dcfg = DistillConfig(teachers=RECORDED_TEACHERS if args.leave_out is None else RECORDED_TEACHERS - 1)
    samples = build_samples(load_recordings(paths), LAYOUT_TDOA_POS, XI_DEFAULT)   # as workflow.distill_kind

    def progress(name: str):  # type: ignore[no-untyped-def]
        return lambda epoch, tr, va: print(f"{name} epoch {epoch} train {tr:.3e} val {va:.3e}", flush=True)
    student, ensemble, report = distill(samples, cfg, dcfg, progress=progress)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.leave_out is not None:
        m = BiasModel(tdoa=student, name=f"util_fold_trial{args.leave_out}_distilled",
                      meta={"replay_cv": f"distilled without trial {args.leave_out}", "trained_on": [p.name for p in paths]})
        m.save(args.out / f"util_fold_trial{args.leave_out}_distilled.npz")
        print(json.dumps({"leave_out": args.leave_out, "hash": m.hash_hex, "trained_on": [p.name for p in paths]}))
        return
    info = {"trained_on": [p.name for p in paths], "distilled": distill_dict(report, dcfg), "folds": {}}
    st = BiasModel(tdoa=student, name="util_tdoa_pos", meta={"replay_cv": "student (the make models recipe)"})
    st.save(args.out / "util_student.npz")
    info["student"] = st.hash_hex
    for label, net in zip(report.folds, ensemble.nets):
        m = BiasModel(tdoa=net, name=f"util_fold_{label}", meta={"replay_cv": f"teacher never trained on {label}"})
        m.save(args.out / f"util_fold_{label}.npz")
        info["folds"][label] = m.hash_hex
    (args.out / "folds.json").write_text(json.dumps(info, indent=2) + "\n")
    print(json.dumps(info, indent=2))


if __name__ == "__main__":
    main()
