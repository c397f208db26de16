"""`make bench`: speed figures, each printed as a ratio against a baseline measured in the same run.

1. Device compute per measurement: the C firmware (its own monotonic-clock figure in RESULT) against the
   numpy twin running the same measurements in this process.
2. Replay of a 120 s simulated flight (all 1 kHz IMU samples and 200 Hz UWB measurements) through the
   host build over a pty: real-time factor per pacing mode, and the pty round trip p50/p99.
3. Bias-network training on ~700k simulated TDoA samples (goal: under 60 s) with `uwb-hil train`'s
   defaults (Adam with the fused update, batch 1024, one intra-op thread), against PyTorch's defaults
   (batch 64, all cores) on the same data.
4. Peak host memory (RSS) of 600 s and 3600 s simulated flights streamed in slices, against the same
   flights built whole (harness/bench/memory.py; goal: 1 hour under 500 MB).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from harness.config import PRESETS, EstimatorConfig
from harness.flight.data import Source
from harness.report.metrics import latency_summary
from harness.device.registry import DeviceSpec, open_device
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE
from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer


def _twin_cost_us(flight: Any, cfg: EstimatorConfig, model: Any) -> np.ndarray:
    """Per-measurement wall time of the numpy twin on the same stream (IMU handling excluded)."""
    from harness.twin.estimator import TwinEstimator
    twin = TwinEstimator(cfg, flight.anchors.as_dict(), model=model)
    u = flight.uwb
    out = []
    for t, src, i in flight.events():
        if src == Source.IMU:
            twin.on_imu(t, flight.imu.acc[i], flight.imu.gyro[i])
            continue
        t0 = time.perf_counter_ns()
        twin.on_meas(u.kind, t, (int(u.anchor_a[i]), int(u.anchor_b[i])), float(u.value[i]))
        out.append((time.perf_counter_ns() - t0) / 1e3)
    return np.asarray(out)


def bench_compute(device: Any, duration_s: float, seed: int) -> list[dict[str, Any]]:
    from harness.biasnet.network import BiasModel
    from harness.flight.scenarios import scenario_flight
    from harness.paths import MODELS_DIR
    model = BiasModel.load(MODELS_DIR / "bias_model_default.npz")
    rows = []
    for mode in ("twr", "tdoa"):
        flight = scenario_flight("circle", mode=mode, duration_s=duration_s, seed=seed)
        cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
        run = Streamer(device).run(flight, cfg, Pacing("windowed", 64))
        fw_us = run.results["compute"][run.results["outcome"] == OUTCOME_RESULT] / 1e3
        twin_us = _twin_cost_us(flight, cfg, model)
        fw = latency_summary(fw_us, 5000.0)
        tw = latency_summary(twin_us, 5000.0)
        rows.append({"mode": mode, "n": fw.n, "firmware_p50_us": fw.p50, "firmware_p99_us": fw.p99,
                     "twin_p50_us": tw.p50, "twin_p99_us": tw.p99,
                     "speedup_p50": tw.p50 / fw.p50 if fw.p50 > 0 else float("inf")})
    return rows


def bench_replay(device: Any, duration_s: float, seed: int, window: int) -> list[dict[str, Any]]:
    from harness.flight.scenarios import scenario_flight
    flight = scenario_flight("circle", mode="twr", duration_s=duration_s, seed=seed)
    cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier+nn"])
    rows = []
    positions = {}
    for pacing in (Pacing("lockstep"), Pacing("windowed", window)):
        run = Streamer(device).run(flight, cfg, pacing)
        ok = run.results["outcome"] == OUTCOME_RESULT
        rtt = latency_summary((run.results["t_recv_ns"][ok] - run.results["t_send_ns"][ok]) / 1e3, 5000.0)
        positions[pacing.mode] = np.stack([run.results[k] for k in ("px", "py", "pz")], axis=1)
        frames = len(flight.uwb) + (len(flight.imu) if flight.imu is not None else 0)
        rows.append({"pacing": pacing.mode, "window": pacing.in_flight, "frames": frames,
                     "sim_s": run.sim_s, "wall_s": run.wall_s, "realtime_factor": run.realtime_factor,
                     "rtt_p50_us": rtt.p50, "rtt_p99_us": rtt.p99, "lost": run.n_lost})
    same = bool(np.array_equal(positions["lockstep"], positions["windowed"]))
    for r in rows:
        r["identical_estimates"] = same
    return rows


def bench_training(samples_wanted: int, baseline_epochs: int) -> dict[str, Any]:
    from dataclasses import replace as dc_replace

    from harness.biasnet.dataset import build_samples
    from harness.biasnet.recipes import SimRecipe
    from harness.biasnet.train import TrainConfig, train_network
    per_flight = 400 * 120  # TDoA2 at 400 Hz, 120 s
    recipe = SimRecipe(mode="tdoa", flights=max(2, -(-samples_wanted // per_flight)), duration_s=120.0, spins=0)
    samples = build_samples(recipe.build())
    default = TrainConfig()
    t0 = time.perf_counter()
    net, rep = train_network(samples, default)
    full_s = time.perf_counter() - t0
    # Throughput of both settings over the same number of epochs (the baseline would take far too long
    # to run to convergence in a benchmark).
    fixed = dc_replace(default, max_epochs=baseline_epochs, patience=baseline_epochs + 1)
    t0 = time.perf_counter()
    _, rep_fast = train_network(samples, fixed)
    fast_s = time.perf_counter() - t0
    base = dc_replace(fixed, batch_size=64, threads=max(1, os.cpu_count() or 1))
    t0 = time.perf_counter()
    _, _ = train_network(samples, base)
    base_s = time.perf_counter() - t0
    return {"samples": len(samples), "train_samples": rep.n_train, "epochs": rep.epochs,
            "stopped_by": rep.stopped_by, "seconds": full_s, "goal_s": 60.0, "within_goal": full_s < 60.0,
            "val_rmse_before_m": rep.val_rmse_before_m, "val_rmse_after_m": rep.val_rmse_after_m,
            "epoch_s_default": fast_s / max(1, rep_fast.epochs), "epoch_s_torch_defaults": base_s / baseline_epochs,
            "speedup": base_s / fast_s if fast_s > 0 else float("inf")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--firmware", default=str(DEFAULT_FIRMWARE))
    ap.add_argument("--replay-duration", type=float, default=120.0)
    ap.add_argument("--compute-duration", type=float, default=30.0)
    ap.add_argument("--window", type=int, default=64)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--train-samples", type=int, default=700_000)
    ap.add_argument("--baseline-epochs", type=int, default=2)
    ap.add_argument("--no-train", action="store_true", help="skip the training benchmark")
    ap.add_argument("--memory-duration", type=float, action="append",
                    help="flight lengths of the memory benchmark [s] (default 600 and 3600)")
    ap.add_argument("--no-memory", action="store_true", help="skip the memory benchmark")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out: dict[str, Any] = {}
    with open_device(DeviceSpec(firmware=Path(args.firmware))) as device:
        out["compute"] = bench_compute(device, args.compute_duration, args.seed)
        out["replay"] = bench_replay(device, args.replay_duration, args.seed, args.window)
    if not args.no_train:
        out["training"] = bench_training(args.train_samples, args.baseline_epochs)
    if not args.no_memory:
        from harness.bench.memory import bench_memory
        durations = args.memory_duration or [600.0, 3600.0]
        out["memory"] = bench_memory(durations, durations, firmware=args.firmware)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print("== per-measurement compute: C firmware (device clock) vs numpy twin (same stream, this process)")
    print(f"{'mode':6} {'n':>6} {'fw p50 us':>10} {'fw p99 us':>10} {'twin p50 us':>12} {'twin p99 us':>12} "
          f"{'speed-up p50':>13}")
    for r in out["compute"]:
        print(f"{r['mode']:6} {r['n']:6d} {r['firmware_p50_us']:10.2f} {r['firmware_p99_us']:10.2f} "
              f"{r['twin_p50_us']:12.1f} {r['twin_p99_us']:12.1f} {r['speedup_p50']:12.0f}x")
    print(f"== replay of a {args.replay_duration:.0f} s flight (IMU 1 kHz + TWR 200 Hz) through the host build "
          "over a pty (ratio = simulated time / wall time)")
    print(f"{'pacing':9} {'window':>6} {'frames':>7} {'wall s':>7} {'x real time':>11} {'RTT p50 us':>10} "
          f"{'RTT p99 us':>10} {'lost':>5}")
    for r in out["replay"]:
        print(f"{r['pacing']:9} {r['window']:6d} {r['frames']:7d} {r['wall_s']:7.2f} "
              f"{r['realtime_factor']:10.0f}x {r['rtt_p50_us']:10.1f} {r['rtt_p99_us']:10.1f} {r['lost']:5d}")
    print(f"lockstep and windowed estimates identical: {out['replay'][0]['identical_estimates']}")
    if "training" in out:
        t = out["training"]
        print(f"== bias-network training: {t['samples']} simulated TDoA samples ({t['train_samples']} train, the rest "
              "validation flights)")
        print(f"full training {t['seconds']:.1f} s ({t['epochs']} epochs, {t['stopped_by']}); goal < {t['goal_s']:.0f} s: "
              f"{'met' if t['within_goal'] else 'NOT met'} ({t['goal_s'] / t['seconds']:.2f}x headroom); validation "
              f"bias RMSE {t['val_rmse_before_m']:.4f} -> {t['val_rmse_after_m']:.4f} m")
        print(f"per epoch: uwb-hil train defaults {t['epoch_s_default']:.2f} s vs PyTorch defaults (batch 64, all cores) "
              f"{t['epoch_s_torch_defaults']:.2f} s: {t['speedup']:.1f}x")
    if "memory" in out:
        from harness.bench.memory import print_rows
        print_rows(out["memory"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
