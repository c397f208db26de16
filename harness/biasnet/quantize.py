"""What the q15 form of a bias network costs (issue 24), and the build option that writes one.

q15.py holds the integer form; here its agreement with the float network (max and RMS, metres) on the
held-out simulated flights and over the input box, and the held-out accuracy cost (RMSE after correction):

    python -m harness.biasnet.quantize [--model firmware_sim/models/bias_model_default.npz] [--quick]
    python -m harness.biasnet.quantize --model M.npz --write M-q15.npz --header M-q15.h   # the build option

``--write`` / ``--header`` save the model with ``quant="q15"`` (its own hash) and its C header, which a
firmware build compiles in (bias_nn_q15.c) when make's MODEL_HEADER names it (docs/bias-network.md; the
harness builds through harness/firmware_build.py, e.g. `uwb-hil run --model M-q15.npz`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from harness.biasnet.network import BiasModel, BiasNetwork
from harness.biasnet.q15 import Q15Network


# ---------------------------------------------------------------------------------- measurement
def agreement(q: Q15Network, features: np.ndarray) -> dict[str, float]:
    """max and RMS of |q15 - float| [m] on the bias (and the std when there is a head)."""
    fb, fs = q.net.predict_with_std_batch(features)
    qb, qs = q.predict_with_std_batch(features)
    out = {"n": int(len(fb)), "bias_max_m": float(np.max(np.abs(qb - fb))),
           "bias_rms_m": float(np.sqrt(np.mean((qb - fb) ** 2)))}
    if q.net.w3s is not None:
        out["std_max_m"] = float(np.max(np.abs(qs - fs)))
    return out


def box_inputs(net: BiasNetwork, n: int, seed: int) -> np.ndarray:
    """n feature rows uniform over the training box (the range the network is trusted in)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 1.0, size=(n, net.n_in))
    return net.in_min + u * (net.in_max - net.in_min)


def heldout_cost(q: Q15Network, kind: str, duration_s: float) -> dict[str, float]:
    """RMSE after correction on the shipped model's held-out simulated flights (the four scenarios with
    seeds 1000-1003, shipped.py), float network vs q15 network, and their agreement there."""
    from harness.biasnet.dataset import build_samples
    from harness.biasnet.recipes import FIRST_EVAL_SEED
    from harness.flight.scenarios import scenario_flight
    test = [scenario_flight(name, mode=kind, duration_s=duration_s, seed=FIRST_EVAL_SEED + k)
            for k, name in enumerate(("circle", "circle-z", "random", "spin"))]
    s = build_samples(test, q.net.layout)
    rf = float(np.sqrt(np.mean((s.bias - q.net.predict_batch(s.x)) ** 2)))
    rq = float(np.sqrt(np.mean((s.bias - q.predict_batch(s.x)) ** 2)))
    return {"n": len(s), "rmse_raw_m": float(np.sqrt(np.mean(s.bias ** 2))), "rmse_float_m": rf, "rmse_q15_m": rq,
            "cost_m": rq - rf, **{f"heldout_{k}": v for k, v in agreement(q, s.x).items()}}


def report(model: BiasModel, duration_s: float, seed: int = 3) -> dict[str, object]:
    out: dict[str, object] = {"model": model.name, "hash": model.hash_hex}
    for kind in ("twr", "tdoa"):
        net = model.network(kind)
        if net is None:
            continue
        q = Q15Network.from_network(net)
        out[kind] = {"exponents": {"a1": q.a1, "a2": q.a2, "w1": q.l1.w_exp, "w2": q.l2.w_exp, "head": q.head.w_exp},
                     "flash_bytes_q15": q.flash_bytes, "box": agreement(q, box_inputs(net, 20000, seed)),
                     "heldout": heldout_cost(q, kind, duration_s)}
    return out


def main(argv: list[str] | None = None) -> int:
    from harness.biasnet.export import DEFAULT_NPZ
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_NPZ)
    ap.add_argument("--duration", type=float, default=70.0, help="seconds per held-out flight (shipped.py: 70)")
    ap.add_argument("--quick", action="store_true", help="10 s held-out flights")
    ap.add_argument("--write", type=Path, default=None, help="save the q15 model (.npz) here instead of measuring")
    ap.add_argument("--header", type=Path, default=None, help="with --write: its C header (export-c) here")
    args = ap.parse_args(argv)
    model = BiasModel.load(args.model)
    if args.write is not None:
        from harness.biasnet.export import export_c
        q = model.quantized("q15")
        q.save(args.write)
        if args.header is not None:
            export_c(q, args.header)
        print(f"wrote {args.write} (hash {q.hash_hex})" + (f" and {args.header}" if args.header else ""))
        return 0
    print(json.dumps(report(model, 10.0 if args.quick else args.duration), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
