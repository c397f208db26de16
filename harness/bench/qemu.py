"""`make bench` (QEMU part): the firmware on the Crazyflie's MCU (STM32F405, Cortex-M4F) under QEMU.

Everything is counted in guest instructions: QEMU runs with `-icount shift=0`, where TIM2 counts one
tick per executed instruction, and the firmware reads TIM2 around each stage. Instruction counts are
exact and identical from run to run; they are not cycles. For the share of a 5 ms slot at 168 MHz we
ASSUME ~2 cycles per instruction (FPU loads/FMAs, taken branches and flash wait states behind the ART
accelerator put real Cortex-M4 code between ~1.3 and ~2.5; the QEMU recipe's static timing model
gives 2.1 for the network). On a real board the DWT cycle counter gives true cycles (docs/qemu.md).

1. Per-measurement instructions: TWR and TDoA updates with and without the bias network, per stage
   (network, gates, EKF update), and the IMU prediction: flights through uwb-fw.elf (M4 network
   kernel) and through a build with the core's portable network (same run).
2. The network alone (uwb-nnbench.elf): the core's portable kernel, the blocked C kernel and the
   assembly kernel on the same inputs, with their largest difference to PyTorch.
3. Flash and RAM (arm-none-eabi-size + the map file), with the network's share.

    python -m harness.bench.qemu [--json] [--duration 3] [--no-build]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Iterator
from contextlib import contextmanager

import numpy as np

from harness.bench.qemu_nn import NN_TOLERANCE, network_kernels
from harness.errors import EXIT_INPUT, InputError
from harness.paths import REPO_ROOT
from protocol.messages import Status

STM32_DIR = REPO_ROOT / "firmware_sim" / "stm32"
BUILD_M4 = REPO_ROOT / "firmware_sim" / "build" / "stm32"
BUILD_PORTABLE = REPO_ROOT / "firmware_sim" / "build" / "stm32-portable"
ELF_M4 = BUILD_M4 / "uwb-fw.elf"
ELF_PORTABLE = BUILD_PORTABLE / "uwb-fw.elf"
BUILD_PROBE = REPO_ROOT / "firmware_sim" / "build" / "stm32-probe"   # nnbench with the probe model

SYSCLK_HZ = 168e6
CYCLES_PER_INSTRUCTION = 2.0          # assumption, see the module docstring
SLOT_S = 5e-3
GOAL_TDOA_NN_INSTR = 20_000
#: Issue 24's goals ("at the MCU's limit"), reported beside the measured figures (not an exit status).
ISSUE24_GOALS = {"tdoa_nn_instructions": 6_000, "predict_instructions": 5_000, "tdoa3_packet_instructions": 9_000,
                 "flash_bytes": 48 * 1024, "ram_bytes": 24 * 1024}


# ------------------------------------------------------------------------------------------ build
def build() -> None:
    """The toolchain (installed when missing), both firmware builds, and the network bench ELF with the
    shipped model and with the probe model (make is incremental)."""
    from harness.stm32_build import build_stm32, build_stm32_with_model, ensure_tools, probe_model
    ensure_tools()
    build_stm32(("fw", "nnbench"))
    build_stm32(("fw",), BUILD_PORTABLE, nn_impl="portable")
    build_stm32_with_model(probe_model(), ("nnbench",), BUILD_PROBE)


def size_figures(build_dir: Path) -> dict[str, Any]:
    proc = subprocess.run([sys.executable, str(STM32_DIR / "size_report.py"), "--elf", str(build_dir / "uwb-fw.elf"),
                           "--map", str(build_dir / "uwb-fw.map"), "--json"],
                          capture_output=True, text=True, timeout=60, check=True)
    return json.loads(proc.stdout)


# ------------------------------------------------------------------------------------------ devices
@contextmanager
def qemu_device(elf: Path, log_dir: Path | None = None, timeout_s: float = 10.0) -> Iterator[Any]:
    from harness.device.registry import DeviceSpec, open_device
    with open_device(DeviceSpec(target="qemu", firmware=elf, log_dir=log_dir, timeout_s=timeout_s)) as device:
        yield device


# ------------------------------------------------------------------------------------------ flights
def flight_for(mode: str, duration_s: float, seed: int, uwb_hz: float = 100.0, imu_hz: float = 500.0) -> Any:
    """A short simulated circle flight: the project's simulator when present, else a synthetic circle.

    The emulated UART moves ~65 us per byte, so the stream is kept light: UWB at `uwb_hz` and the
    simulator's 1 kHz IMU decimated to `imu_hz` (the estimator predicts every 10 ms either way). The
    per-measurement instruction counts do not depend on these rates."""
    try:
        from harness.flight.scenarios import scenario_flight
    except ImportError:
        return synthetic_flight(mode, duration_s, seed, uwb_hz, imu_hz)
    from harness.flight.data import ImuStream
    flight = scenario_flight("circle", mode=mode, duration_s=duration_s, seed=seed, noise="gaussian",
                             noise_std=0.1, rate_hz=uwb_hz)
    imu = flight.imu
    if imu is not None and len(imu) > 1:
        step = max(1, int(round(1e6 / imu_hz / float(np.median(np.diff(imu.t_us))))))
        imu = ImuStream(t_us=imu.t_us[::step], acc=imu.acc[::step], gyro=imu.gyro[::step])
        flight = replace(flight, imu=imu)
        flight.validate()
    return flight


def synthetic_flight(mode: str, duration_s: float, seed: int, uwb_hz: float = 100.0, imu_hz: float = 500.0) -> Any:
    """Level circle (r 1.5 m, 1.5 m up, 0.5 rad/s) in a 4 x 4 x 3 m room with 8 anchors; true IMU;
    Gaussian UWB noise (0.1 m) plus 5 % outliers (+0.8 m) so that the gates have work to do."""
    from harness.flight.data import KIND_TDOA, KIND_TWR, Anchors, Flight, ImuStream, Truth, UwbStream
    rng = np.random.default_rng(seed)
    corners = np.array([[x, y, z] for z in (0.2, 2.8) for x, y in ((-2, -2), (2, -2), (2, 2), (-2, 2))], float)
    anchors = Anchors(ids=np.arange(8), positions=corners)
    r, w, c = 1.5, 0.5, np.array([0.0, 0.0, 1.5])

    def pos(t: np.ndarray) -> np.ndarray:
        return c + np.stack([r * np.cos(w * t), r * np.sin(w * t), np.zeros_like(t)], axis=1)

    t_imu = np.arange(0.0, duration_s, 1.0 / imu_hz)
    acc = np.stack([-r * w * w * np.cos(w * t_imu), -r * w * w * np.sin(w * t_imu), np.full_like(t_imu, 9.81)], axis=1)
    imu = ImuStream(t_us=(t_imu * 1e6).astype(np.int64), acc=acc, gyro=np.zeros_like(acc))
    t_uwb = np.arange(0.01, duration_s, 1.0 / uwb_hz)
    n = len(t_uwb)
    p = pos(t_uwb)
    a = np.arange(n) % 8
    if mode == "twr":
        b = np.full(n, -1)
        true = np.linalg.norm(p - corners[a], axis=1)
        kind = KIND_TWR
    else:
        b = (a + 1 + np.arange(n) // 8 % 7) % 8
        true = np.linalg.norm(p - corners[b], axis=1) - np.linalg.norm(p - corners[a], axis=1)
        kind = KIND_TDOA
    value = true + rng.normal(0.0, 0.1, n) + np.where(rng.uniform(size=n) < 0.05, 0.8, 0.0)
    t_truth = np.arange(0.0, duration_s + 0.01, 0.005)
    truth = Truth(t_us=(t_truth * 1e6).astype(np.int64), pos=pos(t_truth))
    uwb = UwbStream(kind=kind, t_us=(t_uwb * 1e6).astype(np.int64), anchor_a=a, anchor_b=b, value=value,
                    true_value=true)
    flight = Flight(name=f"synthetic-circle-{mode}", anchors=anchors, uwb=uwb, truth=truth, imu=imu)
    flight.validate()
    return flight


# ------------------------------------------------------------------------------------------ stages
@dataclass
class StageRow:
    build: str            # "m4" | "portable"
    mode: str             # "twr" | "tdoa"
    network: bool
    n: int                # measurements with an EKF update (status ACCEPTED)
    compute: float        # median instructions of the whole measurement (estimator call)
    compute_max: int
    nn: float
    gates: float
    update: float
    predict_per_call: float   # instructions per IMU prediction (0 if none ran)
    predictions: int
    frames: int               # IMU + UWB frames streamed
    sim_s: float              # simulated seconds
    wall_s: float             # host seconds the replay took (the emulated UART is the bottleneck)
    states: bool = False      # with the per-anchor bias states (stage BIAS_STATES)


def _median(a: np.ndarray) -> float:
    return float(np.median(a)) if len(a) else float("nan")


def stage_costs(device: Any, build_name: str, duration_s: float, seed: int) -> list[StageRow]:
    from harness.config import PRESETS, EstimatorConfig
    from harness.flight.run_config import config_for
    from harness.stream.streamer import OUTCOME_RESULT, Pacing, Streamer

    rows = []
    streamer = Streamer(device, timeout_s=20.0)
    presets = ("outlier", "outlier+nn", "outlier+nn+states") if build_name == "m4" else ("outlier+nn",)
    for mode in ("twr", "tdoa"):
        flight = flight_for(mode, duration_s, seed)
        for preset in presets:
            cfg = config_for(flight, EstimatorConfig(), stages=PRESETS[preset])
            before = streamer.channel.stats(streamer.timeout_s)   # device counters are cumulative
            run = streamer.run(flight, cfg, Pacing("windowed", 16))
            res = run.results
            ok = (res["outcome"] == OUTCOME_RESULT) & (res["status"] == Status.ACCEPTED)
            if preset != "outlier":
                ok &= res["cost_nn"] > 0   # the network ran (it is skipped below nn_min_z)
            preds = int(run.stats.predictions) - int(before.predictions) if run.stats is not None else 0
            pred_total = int(np.sum(res["cost_predict"][res["outcome"] == OUTCOME_RESULT], dtype=np.int64))
            rows.append(StageRow(
                build=build_name, mode=mode, network=preset != "outlier", n=int(ok.sum()),
                compute=_median(res["compute"][ok]), compute_max=int(res["compute"][ok].max()) if ok.any() else 0,
                nn=_median(res["cost_nn"][ok]), gates=_median(res["cost_gates"][ok]),
                update=_median(res["cost_update"][ok]),
                predict_per_call=pred_total / preds if preds else 0.0, predictions=preds,
                frames=len(flight.uwb) + (len(flight.imu) if flight.imu is not None else 0),
                sim_s=run.sim_s, wall_s=run.wall_s, states=preset.endswith("+states")))
    return rows


# ------------------------------------------------------------------------------------------ report
def _share(instr: float) -> tuple[float, float, float]:
    cycles = instr * CYCLES_PER_INSTRUCTION
    us = cycles / SYSCLK_HZ * 1e6
    return cycles, us, 100.0 * us * 1e-6 / SLOT_S


def print_report(out: dict[str, Any]) -> None:
    print("== STM32F405 (Cortex-M4F) under QEMU -icount shift=0: guest instructions per measurement"
          f" (shipped model hash {out.get('model_hash', '?')})")
    print(f"   median over measurements with an EKF update; cycles ASSUMED = {CYCLES_PER_INSTRUCTION:g} x instructions;"
          f" slot = 5 ms at 168 MHz ({SLOT_S * SYSCLK_HZ:,.0f} cycles)")
    hdr = f"{'measurement':37} {'n':>5} {'instr':>8} {'~cycles':>8} {'~us':>7} {'% slot':>7}   {'network':>7} {'gates':>6} {'update':>7}"
    print(hdr)
    for r in out["stages"]:
        label = f"{r['mode'].upper()} update" + (f" + network ({r['build']})" if r["network"] else ", no network")
        label += " + states" if r.get("states") else ""
        cyc, us, pct = _share(r["compute"])
        print(f"{label:37} {r['n']:5d} {r['compute']:8.0f} {cyc:8.0f} {us:7.1f} {pct:6.2f}%   "
              f"{r['nn']:7.0f} {r['gates']:6.0f} {r['update']:7.0f}")
    preds = [r for r in out["stages"] if r["predictions"] > 0]
    if preds:
        p = float(np.median([r["predict_per_call"] for r in preds]))
        cyc, us, pct = _share(p)
        print(f"{'IMU prediction (per prediction)':37} {sum(r['predictions'] for r in preds):5d} {p:8.0f} {cyc:8.0f} "
              f"{us:7.1f} {pct:6.2f}%")
    g = out["goals"]
    print(f"goal: TDoA update incl. network <= {GOAL_TDOA_NN_INSTR:,} instructions: {g['tdoa_nn_instructions']:,.0f} "
          f"-> {'OK' if g['tdoa_nn_ok'] else 'MISSED'}")
    if "radio" in out:
        from harness.bench.radio import format_row
        print("radio level: " + format_row(out["radio"]))
    if "issue24" in g:
        print("issue 24 goals: " + ", ".join(f"{k} {v['value']:,.0f} <= {v['goal']:,} {'OK' if v['ok'] else 'MISSED'}"
                                             for k, v in g["issue24"].items()))
    print("== bias network alone (uwb-nnbench.elf, same run, same inputs): instructions per call")
    print("   shipped = firmware_sim/models/bias_model_default.h; probe = random network of the same shapes whose")
    print("   outputs stay inside the clamp (harness/stm32_build.py), so the PyTorch check tests every output")
    print(f"{'model':8} {'kernel':32} {'net':5} {'instr':>8} {'speed-up':>9} {'max |y - PyTorch|':>18}"
          f" {'unclamped':>9} {'std(y) m':>9}")
    for r in out["network"]:
        print(f"{r['model']:8} {r['kernel']:32} {r['kind']:5} {r['instructions']:8.0f} {r['speedup']:8.2f}x "
              f"{r['max_err_torch']:18.2e} {100 * r['unclamped']:8.0f}% {r['ref_std']:9.3g}")
    print(f"all kernels within {NN_TOLERANCE:g} of PyTorch: {g['nn_within_tolerance']}")
    if any(r["ref_std"] == 0.0 for r in out["network"] if r["model"] == "shipped"):
        print("   note: the shipped model's output is constant (untrained output layer): its PyTorch check is"
              " vacuous, the probe's is not")
    s = out["size"]
    print("== size (arm-none-eabi-size, uwb-fw.elf with the M4 kernel)")
    print(f"flash {s['flash']:,} B (goal <= 49,152: {'OK' if s['flash'] <= 49152 else 'OVER'}), "
          f"RAM {s['ram']:,} B incl. {s['stack_reserved']:,} B stack (goal <= 32,768: {'OK' if s['ram'] <= 32768 else 'OVER'}); "
          f"network {s['network_flash']:,} B flash = {100.0 * s['network_flash'] / s['flash']:.1f}% "
          f"(weights {s['network_weights']:,} B)")
    print(f"stack high-water mark after the flights: {s['stack_high_water']:,} B of {s['stack_reserved']:,} B reserved")
    frames = sum(r["frames"] for r in out["stages"])
    wall = sum(r["wall_s"] for r in out["stages"])
    sim = sum(r["sim_s"] for r in out["stages"])
    print(f"== link: {frames:,} frames ({sim:.0f} s simulated) streamed in {wall:.0f} s through the emulated USART "
          f"({sim / wall:.2f}x real time; host-load dependent, QEMU moves ~1 byte per main-loop iteration)")


def run_bench(duration_s: float, seed: int, nn_inputs: int, do_build: bool, log_dir: Path | None,
              build_m4: Path = BUILD_M4, build_portable: Path = BUILD_PORTABLE,
              build_probe: Path = BUILD_PROBE) -> dict[str, Any]:
    if do_build:
        build()
    elfs = (build_m4 / "uwb-fw.elf", build_portable / "uwb-fw.elf", build_m4 / "uwb-nnbench.elf",
            build_probe / "uwb-nnbench.elf")
    if missing := [str(e) for e in elfs if not e.is_file()]:
        raise InputError(f"bench.qemu: not built: {', '.join(missing)} (run without --no-build, or make bench)")
    out: dict[str, Any] = {"cycles_per_instruction_assumed": CYCLES_PER_INSTRUCTION, "sysclk_hz": SYSCLK_HZ}
    stages: list[StageRow] = []
    stack_used: dict[str, int] = {}
    for name, elf in (("m4", build_m4 / "uwb-fw.elf"), ("portable", build_portable / "uwb-fw.elf")):
        with qemu_device(elf, log_dir) as dev:
            stages += stage_costs(dev, name, duration_s, seed)
            if name == "m4":
                from harness.bench.radio import radio_stage
                out["radio"] = asdict(radio_stage(dev, duration_s, seed))
            stack_used[name] = dev.stack_high_water()   # the deepest the flights took the painted stack
            out["model_hash"] = dev.identity.as_dict()["model_hash"]
    out["stages"] = [asdict(r) for r in stages]
    kernels = network_kernels(nn_inputs, seed, log_dir, build_m4 / "uwb-nnbench.elf", "shipped")
    kernels += network_kernels(nn_inputs, seed, log_dir, build_probe / "uwb-nnbench.elf", "probe")
    out["network"] = [asdict(r) for r in kernels]
    out["size"] = size_figures(build_m4)
    out["size"]["stack_high_water"] = stack_used["m4"]
    out["size_portable"] = size_figures(build_portable)
    tdoa_nn = [r for r in stages if r.build == "m4" and r.mode == "tdoa" and r.network]
    tdoa_instr = max((r.compute for r in tdoa_nn), default=float("nan"))  # with or without the bias states
    out["goals"] = {
        "tdoa_nn_instructions": tdoa_instr, "tdoa_nn_ok": bool(tdoa_instr <= GOAL_TDOA_NN_INSTR),
        "flash_ok": out["size"]["flash"] <= 49152, "ram_ok": out["size"]["ram"] <= 32768,
        "nn_within_tolerance": all(r["max_err_torch"] <= NN_TOLERANCE for r in out["network"]),
        "radio_tdoa3_instructions": out["radio"]["compute"],
        "radio_tdoa3_ok": bool(out["radio"]["compute"] <= 25_000),
    }
    out["goals"]["issue24"] = issue24_goals(out, tdoa_instr)
    return out


def issue24_goals(out: dict[str, Any], tdoa_instr: float) -> dict[str, dict[str, float | bool]]:
    """Each of issue 24's goals: the measured value, the goal and whether it is met."""
    preds = [r["predict_per_call"] for r in out["stages"] if r["predictions"] > 0]
    measured = {"tdoa_nn_instructions": tdoa_instr,
                "predict_instructions": float(np.median(preds)) if preds else float("nan"),
                "tdoa3_packet_instructions": out["radio"]["compute"],
                "flash_bytes": out["size"]["flash"], "ram_bytes": out["size"]["ram"]}
    return {k: {"value": v, "goal": ISSUE24_GOALS[k], "ok": bool(v <= ISSUE24_GOALS[k])} for k, v in measured.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=3.0, help="simulated seconds per flight (QEMU's UART is slow)")
    ap.add_argument("--nn-inputs", type=int, default=200, help="random inputs per network for the kernel bench")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--no-build", action="store_true", help="use the ELFs already built")
    ap.add_argument("--log-dir", type=Path, default=None, help="keep QEMU logs here")
    ap.add_argument("--build-dir", type=Path, default=BUILD_M4, help="where uwb-fw.elf/uwb-nnbench.elf are")
    ap.add_argument("--portable-build-dir", type=Path, default=BUILD_PORTABLE,
                    help="where the NN_IMPL=portable uwb-fw.elf is")
    ap.add_argument("--probe-build-dir", type=Path, default=BUILD_PROBE,
                    help="where the probe-model uwb-nnbench.elf is")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        out = run_bench(args.duration, args.seed, args.nn_inputs, not args.no_build, args.log_dir,
                        args.build_dir, args.portable_build_dir, args.probe_build_dir)
    except InputError as e:
        print(e, file=sys.stderr)
        return EXIT_INPUT
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print_report(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
