"""Issue 14 item 4: do anchor identity or velocity add to the position-only UTIL network?

    python scripts/input_probe.py [--epochs 300] [--seed 0]

Trains the same 2 x 50 ReLU network (Adam, batch 512, early stopping on whole validation flights, as
`make models` trains util_tdoa_pos) on UTIL const1/const2 trials 1-4 with four input sets, and reports each
one's measurement RMSE and share of the ceiling on the held-out trial-5 flights:
  pos        dp_A, dp_B (the shipped layout TDOA_POS)
  +id        plus one-hot anchor ids of A and B
  +vel       plus the tag's world velocity (true, central difference over +-50 ms: what a good estimate gives)
  +id+vel    both
Measurement level only, with inputs from the truth (like training): an upper bound of what the input
could add in the firmware, which would have to compute it from its estimate.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.biasnet.ceiling import fast_residual, share_of_ceiling
from harness.biasnet.dataset import LAYOUT_TDOA_POS, Samples, build_samples, split_by_flight
from harness.biasnet.recipes import load_recordings
from harness.flight.data import Flight
from harness.optional import require_torch
from harness.paths import shared_data_dir

N_IDS = 16


def velocity(flights: list[Flight], s: Samples) -> np.ndarray:
    out = np.zeros((len(s), 3))
    for k, f in enumerate(flights):
        m = s.flight == k
        t = f.uwb.t_us[s.row[m]].astype(np.float64)
        out[m] = (f.truth.position_at(t + 5e4) - f.truth.position_at(t - 5e4)) / 0.1
    return out


def inputs(flights: list[Flight], s: Samples, which: str) -> np.ndarray:
    cols = [s.x]
    if "id" in which:
        onehot = np.zeros((len(s), 2 * N_IDS))
        onehot[np.arange(len(s)), s.pair[:, 0]] = 1.0
        onehot[np.arange(len(s)), N_IDS + s.pair[:, 1]] = 1.0
        cols.append(onehot)
    if "vel" in which:
        cols.append(velocity(flights, s))
    return np.concatenate(cols, axis=1)


def fit_predict(x: np.ndarray, y: np.ndarray, val: np.ndarray, x_test: list[np.ndarray], epochs: int,
                seed: int) -> list[np.ndarray]:
    torch = require_torch("the input probe")
    torch.manual_seed(seed)
    torch.set_num_threads(1)
    lo, hi = x[~val].min(axis=0), x[~val].max(axis=0)
    span = np.where(hi - lo < 1e-6, 1.0, hi - lo)
    y_lo, y_span = float(y.min()), float(np.ptp(y))

    def t(a: np.ndarray) -> "torch.Tensor":
        return torch.from_numpy(((a - lo) / span).astype(np.float32))

    xt, xv = t(x[~val]), t(x[val])
    yt = torch.from_numpy(((y[~val] - y_lo) / y_span).astype(np.float32))
    yv = torch.from_numpy(((y[val] - y_lo) / y_span).astype(np.float32))
    nn = torch.nn
    net = nn.Sequential(nn.Linear(x.shape[1], 50), nn.ReLU(), nn.Linear(50, 50), nn.ReLU(), nn.Linear(50, 1))
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(seed)
    best, best_state, since = float("inf"), None, 0
    for _ in range(epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for k in range(0, len(xt), 512):
            idx = perm[k:k + 512]
            opt.zero_grad(set_to_none=True)
            loss = torch.mean((net(xt[idx]).squeeze(1) - yt[idx]) ** 2)
            loss.backward()
            opt.step()
        with torch.no_grad():
            v = float(torch.mean((net(xv).squeeze(1) - yv) ** 2))
        if v < best - 1e-7:
            best, best_state, since = v, [p.detach().clone() for p in net.parameters()], 0
        else:
            since += 1
            if since >= 12:
                break
    with torch.no_grad():
        for p, b in zip(net.parameters(), best_state or []):
            p.copy_(b)
        return [net(t(a)).squeeze(1).numpy().astype(np.float64) * y_span + y_lo for a in x_test]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    d = shared_data_dir() / "util"
    anchors = d / "anchors.csv"
    train_paths = sorted(p for c in ("const1", "const2") for k in range(1, 5) for p in (d / c).glob(f"{c}-trial{k}-*.csv"))
    test_paths = [d / "const1/const1-trial5-tdoa2-extracted.csv", d / "const1/const1-trial5-tdoa3-extracted.csv",
                  d / "const2/const2-trial5-tdoa2-extracted.csv"]
    tr_f = load_recordings(train_paths, anchors)
    tr = build_samples(tr_f, LAYOUT_TDOA_POS)
    _, val = split_by_flight(tr, 0.15, args.seed)
    tests = [(p, [f], build_samples([f], LAYOUT_TDOA_POS)) for p, f in zip(test_paths, load_recordings(test_paths, anchors))]
    print(f"train {len(tr)} samples ({len(tr_f)} flights), held out: trial 5")
    print(f"{'inputs':10} " + " ".join(f"{p.stem[:22]:>34}" for p, _, _ in tests))
    for which in ("pos", "+id", "+vel", "+id+vel"):
        preds = fit_predict(inputs(tr_f, tr, which), tr.bias, val,
                            [inputs(fl, s, which) for _, fl, s in tests], args.epochs, args.seed)
        cells = []
        for (_, _, s), pred in zip(tests, preds):
            raw, corr = float(np.sqrt(np.mean(s.bias ** 2))), float(np.sqrt(np.mean((s.bias - pred) ** 2)))
            floor = float(np.sqrt(np.mean(fast_residual(s) ** 2)))
            cells.append(f"{corr:.4f} m {100 * (1 - corr / raw):5.1f} % cut {100 * share_of_ceiling(raw, corr, floor):3.0f} %")
        print(f"{which:10} " + " ".join(f"{c:>34}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
