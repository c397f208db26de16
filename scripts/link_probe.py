"""Per-link TDoA bias network against the shipped recipe, by inner cross-validation on UTIL trials 1-4.

    python scripts/link_probe.py [--seeds 0 1] [--trials 1 2 3 4] [--variants dp dpn dp_pair] [--json out.json]
    python scripts/link_probe.py --rows-from s0.json s1.json     # one table of runs made separately

Idea: a TDoA bias is the difference of two per-link biases, bias_AB ~= h(dp_B) - h(dp_A) (+ c), with one
network h (2 x 50 ReLU, the paper's size) shared by every link, dp = anchor - tag. Trained through that
difference on the TDoA samples, h sees every link of every pair (TDoA3's arbitrary pairs all inform it).

For every training trial j of 1-4 (trial 5 is never loaded): train on the const1/const2 tdoa2 + tdoa3
flights of the other three trials together (as the shipped UTIL model), judge on trial j's three sets
(const1 tdoa2, const1 tdoa3, const2 tdoa2):

* voxel      the voxel table fitted on the same three trials (the issue's reference);
* A          the shipped recipe (layout 4 TDOA_POS, distilled: one teacher per training trial, seed*K+k, then
             one student; harness/biasnet/distill.py), and its teacher (mean of the K networks), "A-teacher";
* link-V     for each variant V, K link networks on the same folds and seeds as A's teachers (network k
             validated on one whole training trial, trained on the other two: the shipped early-stopping
             convention), their mean ("the link teacher"), and the mean cut of the single networks:
               dp       h(dp)
               dpn      h(dp, |dp|)
               dp_pair  h(dp) + a learned constant per anchor pair (0 for a pair not seen in training)

Printed per left-out set: RMSE cut [%], share of the ceiling (literal floor, harness/biasnet/ceiling.py),
gain over the voxel table [points]; then the decision rule, fixed before trial 5 is looked at: adopt a link
network only if, over the 12 left-out sets, its mean gain over A (the distilled student) is >= +1 point of
RMSE cut and it is worse than A on at most 3 sets. The link teacher is judged (a shipped link network
would be its distilled student, which loses 0.1-0.4 points to its teacher in the A recipe), so a link
variant that fails here would fail as a student too.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from harness.biasnet.baselines import VoxelTable
from harness.biasnet.ceiling import fast_part, share_of_ceiling
from harness.biasnet.dataset import Samples, build_samples
from harness.biasnet.distill import DistillConfig, distill, flight_groups
from harness.biasnet.network import HIDDEN
from harness.biasnet.recipes import load_recordings, util_files
from harness.biasnet.train import TrainConfig
from harness.optional import require_torch
from harness.paths import SHARED_DATA
from harness.twin.features import LAYOUT_TDOA_POS

VARIANTS = ("dp", "dpn", "dp_pair")


def link_inputs(x: np.ndarray, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """Inputs of h for anchor A and anchor B of every TDoA row (layout 4: dp_A, dp_B)."""
    a, b = x[:, 0:3], x[:, 3:6]
    if variant == "dpn":
        a = np.concatenate([a, np.linalg.norm(a, axis=1, keepdims=True)], axis=1)
        b = np.concatenate([b, np.linalg.norm(b, axis=1, keepdims=True)], axis=1)
    return a, b


@dataclass
class LinkNet:
    """A trained link network: h in torch, its input scaling, the pair constants, the output clamp."""

    h: Any
    lo: np.ndarray
    span: np.ndarray
    scale: float
    out_min: float
    out_max: float
    variant: str
    pair_index: dict[int, int]
    pair_const: np.ndarray  # [m], one per entry of pair_index
    best_epoch: int
    seconds: float

    def predict(self, s: Samples) -> np.ndarray:
        torch = require_torch("the link probe")
        a, b = link_inputs(s.x, self.variant)
        with torch.no_grad():
            ha = self.h(torch.from_numpy(((a - self.lo) / self.span).astype(np.float32)))[:, 0].numpy()
            hb = self.h(torch.from_numpy(((b - self.lo) / self.span).astype(np.float32)))[:, 0].numpy()
        y = (hb.astype(np.float64) - ha) * self.scale
        if self.pair_const.size:
            idx = np.array([self.pair_index.get(int(k), -1) for k in s.pair_keys()])
            y = y + np.where(idx >= 0, self.pair_const[np.maximum(idx, 0)], 0.0)
        return np.clip(y, self.out_min, self.out_max)


def train_link(train: Samples, val: Samples, variant: str, cfg: TrainConfig) -> LinkNet:
    """h trained through bias_AB = h(dp_B) - h(dp_A) (+ c_AB), the shipped optimizer and early stopping."""
    torch = require_torch("the link probe")
    nn = torch.nn
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    a, b = link_inputs(train.x, variant)
    both = np.concatenate([a, b])
    lo, hi = both.min(axis=0), both.max(axis=0)
    span = np.maximum(hi - lo, 1e-6)
    out_min, out_max = float(train.bias.min()), float(train.bias.max())
    scale = out_max - out_min  # the target is scaled by the shipped network's range; constants cancel
    pair_index: dict[int, int] = {}
    if variant == "dp_pair":
        pair_index = {int(k): i for i, k in enumerate(np.unique(train.pair_keys()))}

    def tensors(s: Samples) -> tuple[Any, Any, Any, Any]:
        xa, xb = link_inputs(s.x, variant)
        pid = np.zeros(len(s), dtype=np.int64)
        if pair_index:  # a validation pair not seen in training gets its own (untrained, zero) slot
            pid = np.array([pair_index.get(int(k), len(pair_index)) for k in s.pair_keys()], dtype=np.int64)
        return (torch.from_numpy(((xa - lo) / span).astype(np.float32)),
                torch.from_numpy(((xb - lo) / span).astype(np.float32)),
                torch.from_numpy(pid), torch.from_numpy((s.bias / scale).astype(np.float32)))

    class Link(nn.Module):  # type: ignore[misc, name-defined]
        def __init__(self) -> None:
            super().__init__()
            self.h = nn.Sequential(nn.Linear(a.shape[1], HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
                                   nn.Linear(HIDDEN, 1))
            self.c = nn.Parameter(torch.zeros(len(pair_index) + 1)) if pair_index else None

        def forward(self, xa: Any, xb: Any, pid: Any) -> Any:
            y = self.h(torch.cat([xa, xb]))[:, 0]
            d = y[len(xa):] - y[:len(xa)]
            return d + self.c[pid] if self.c is not None else d

    tr, va = tensors(train), tensors(val)
    net = Link()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, fused=True)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=max(1, cfg.patience // 3))
    gen = torch.Generator().manual_seed(cfg.seed)
    best = (float("inf"), [p.detach().clone() for p in net.parameters()], 0)
    since = 0
    t0 = time.perf_counter()
    n = len(tr[0])
    for epoch in range(1, cfg.max_epochs + 1):
        net.train()
        perm = torch.randperm(n, generator=gen)
        xa, xb, pid, y = (t[perm] for t in tr)
        for k in range(0, n, cfg.batch_size):
            sl = slice(k, k + cfg.batch_size)
            opt.zero_grad(set_to_none=True)
            loss = torch.mean((net(xa[sl], xb[sl], pid[sl]) - y[sl]) ** 2)
            loss.backward()
            opt.step()
        net.eval()
        with torch.no_grad():
            vloss = float(torch.mean((net(*va[:3]) - va[3]) ** 2))
        sched.step(vloss)
        if vloss < best[0] - cfg.min_delta:
            best = (vloss, [p.detach().clone() for p in net.parameters()], epoch)
            since = 0
        else:
            since += 1
            if since >= cfg.patience:
                break
    with torch.no_grad():
        for p, v in zip(net.parameters(), best[1]):
            p.copy_(v)
    const = (net.c.detach().numpy()[:len(pair_index)].astype(np.float64) * scale if net.c is not None
             else np.zeros(0))
    return LinkNet(net.h.eval(), lo, span, scale, out_min, out_max, variant, pair_index, const, best[2],
                   time.perf_counter() - t0)


def link_teachers(samples: Samples, variant: str, cfg: TrainConfig, k_teachers: int) -> list[LinkNet]:
    """The A recipe's teacher folds: network k validated on group k, trained on the rest, seed*K + k."""
    group_of_flight, labels = flight_groups(samples.names)
    group = group_of_flight[samples.flight]
    nets = []
    for k in range(k_teachers):
        val_mask = group == k % len(labels)
        nets.append(train_link(samples.subset(~val_mask), samples.subset(val_mask), variant,
                               replace(cfg, seed=cfg.seed * k_teachers + k)))
    return nets


def cut(raw: np.ndarray, corrected: np.ndarray) -> float:
    return 100.0 * (1.0 - float(np.sqrt(np.mean(corrected ** 2)) / np.sqrt(np.mean(raw ** 2))))


def rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


def set_name(path: Path) -> str:
    parts = path.name.split("-")  # constC-trialT-tdoaN-extracted.csv
    return f"{parts[0]} {parts[2]}"


def run_fold(data: Path, seed: int, j: int, variants: list[str], log: Any) -> list[dict[str, Any]]:
    others = tuple(t for t in (1, 2, 3, 4) if t != j)
    train = build_samples(load_recordings(util_files(data, others)), LAYOUT_TDOA_POS)
    cfg = TrainConfig(max_epochs=300, patience=12, batch_size=512, seed=seed, std_head=None)
    t0 = time.perf_counter()
    student, teacher, _ = distill(train, cfg, DistillConfig(teachers=len(others)))
    log(f"seed {seed} trial {j}: A distilled in {time.perf_counter() - t0:.0f} s")
    voxel = VoxelTable().fit(train)
    links: dict[str, list[LinkNet]] = {}
    for v in variants:
        t0 = time.perf_counter()
        links[v] = link_teachers(train, v, cfg, len(others))
        log(f"seed {seed} trial {j}: link {v} in {time.perf_counter() - t0:.0f} s, best epochs "
            f"{[n.best_epoch for n in links[v]]}")
    rows = []
    for path in util_files(data, (j,)):
        te = build_samples(load_recordings([path]), LAYOUT_TDOA_POS)
        raw = rmse(te.bias)
        floor = fast_part(te).floor()
        preds: dict[str, np.ndarray] = {"voxel": voxel.predict(te), "A": student.predict_batch(te.x),
                                        "A-teacher": teacher.predict_batch(te.x)}
        singles: dict[str, float] = {}
        for v, nets in links.items():
            p = [n.predict(te) for n in nets]
            preds[f"link-{v}"] = np.mean(p, axis=0)
            singles[f"link-{v}-single"] = statistics.mean(cut(te.bias, te.bias - q) for q in p)
        methods = {}
        for name, p in preds.items():
            corr = te.bias - p
            methods[name] = {"cut": cut(te.bias, corr), "share": 100.0 * share_of_ceiling(raw, rmse(corr), floor)}
        for name, c in singles.items():
            corr_rmse = raw * (1.0 - c / 100.0)
            methods[name] = {"cut": c, "share": 100.0 * share_of_ceiling(raw, corr_rmse, floor)}
        rows.append({"seed": seed, "trial": j, "set": set_name(path), "n": len(te), "rmse_raw": raw,
                     "floor": floor, "methods": methods})
        log(f"seed {seed} trial {j} {set_name(path)}: " +
            ", ".join(f"{k} {m['cut']:.1f} %" for k, m in methods.items()))
    return rows


def summary(rows: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    """Per (trial, set), averaged over seeds; then per method the gains over voxel and over A."""
    keys = sorted({(r["trial"], r["set"]) for r in rows})
    table = {}
    for key in keys:
        rs = [r for r in rows if (r["trial"], r["set"]) == key]
        table[key] = {m: {q: statistics.mean(r["methods"][m][q] for r in rs) for q in ("cut", "share")}
                      for m in methods}
    out: dict[str, Any] = {"sets": [{"trial": k[0], "set": k[1], **table[k]} for k in keys], "methods": {}}
    for m in methods:
        over_voxel = [table[k][m]["cut"] - table[k]["voxel"]["cut"] for k in keys]
        over_a = [table[k][m]["cut"] - table[k]["A"]["cut"] for k in keys]
        out["methods"][m] = {"mean_cut": statistics.mean(table[k][m]["cut"] for k in keys),
                             "mean_share": statistics.mean(table[k][m]["share"] for k in keys),
                             "gain_over_voxel": statistics.mean(over_voxel), "worst_over_voxel": min(over_voxel),
                             "gain_over_A": statistics.mean(over_a), "sets_worse_than_A": sum(g < 0 for g in over_a),
                             "adopt": (m.startswith("link-") and not m.endswith("-single")
                                       and statistics.mean(over_a) >= 1.0 and sum(g < 0 for g in over_a) <= 3)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=SHARED_DATA)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--trials", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--json", type=Path, help="write every figure here")
    ap.add_argument("--rows-from", type=Path, nargs="+", metavar="JSON",
                    help="train nothing: print the table of the rows of earlier --json files (e.g. one per seed)")
    args = ap.parse_args()
    if not set(args.trials) <= {1, 2, 3, 4}:
        ap.error("--trials must be among 1-4 (trial 5 is the held-out set)")

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    rows = []
    if args.rows_from:
        try:
            for f in args.rows_from:
                rows.extend(json.loads(f.read_text())["rows"])
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"--rows-from: cannot read rows from {f}: {e!r}", file=sys.stderr)
            return 2
        if not rows:
            print("--rows-from: the files hold no rows", file=sys.stderr)
            return 2
        args.seeds = sorted({r["seed"] for r in rows})
        args.trials = sorted({r["trial"] for r in rows})
    elif not util_files(args.data, tuple(args.trials)):
        print(f"no UTIL recordings under {args.data}/util", file=sys.stderr)
        return 2
    else:
        for seed in args.seeds:
            for j in args.trials:
                rows.extend(run_fold(args.data, seed, j, args.variants, log))
    methods = list(rows[0]["methods"])
    s = summary(rows, methods)
    print(f"seeds {args.seeds}; RMSE cut % / share of the ceiling % (literal floor), mean over seeds")
    print("| trial | set | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for r in s["sets"]:
        print(f"| {r['trial']} | {r['set']} | " +
              " | ".join(f"{r[m]['cut']:.1f} / {r[m]['share']:.0f}" for m in methods) + " |")
    print("\n| method | mean cut | mean share | gain over voxel (worst) | gain over A | sets worse than A | adopt |")
    print("|---|---|---|---|---|---|---|")
    for m, v in s["methods"].items():
        print(f"| {m} | {v['mean_cut']:.2f} | {v['mean_share']:.1f} | {v['gain_over_voxel']:+.2f} "
              f"({v['worst_over_voxel']:+.2f}) | {v['gain_over_A']:+.2f} | {v['sets_worse_than_A']} | "
              f"{'yes' if v['adopt'] else '-'} |")
    if args.json:
        args.json.write_text(json.dumps({"seeds": args.seeds, "trials": args.trials, "variants": args.variants,
                                         "rows": rows, "summary": s}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
