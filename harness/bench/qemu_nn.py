"""`make bench` (QEMU part), the network alone: uwb-nnbench.elf (firmware_sim/stm32/nnbench_main.c) runs the
core's portable kernel, the blocked C kernel and the assembly kernel on the same inputs; each output is
compared with PyTorch on the same weights (dumped from the device). harness/bench/qemu.py reports it."""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from harness.errors import DeviceError
from harness.paths import DEFAULT_STM32_ELF

ELF_NNBENCH = DEFAULT_STM32_ELF.parent / "uwb-nnbench.elf"
NN_TOLERANCE = 1e-5


class BenchError(DeviceError, RuntimeError):
    """The network-bench image answered wrongly or not in time (exit 3, as any device failure)."""


@dataclass
class KernelRow:
    model: str                 # "shipped" (firmware_sim/models) | "probe" (harness/stm32_build.py)
    kernel: str
    kind: str
    n_in: int                  # network inputs (6/9 with attitude, 3/6 without)
    n: int
    instructions: float        # median per call
    speedup: float             # portable / this
    max_err_torch: float       # max |y - PyTorch|
    unclamped: float           # share of reference outputs strictly inside (out_min, out_max)
    ref_std: float             # spread of the reference outputs [m]; 0 = constant network (check vacuous)


KERNELS = ("portable (core bias_nn.c)", "C blocked (nn_m4.c)", "asm VLDM+VFMA (nn_m4_kernel.S)")


@dataclass
class NetTables:
    """One compiled-in network as dumped by uwb-nnbench.elf (w1 input-major: n_in x 50)."""
    n_in: int
    in_min: np.ndarray
    in_max: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    w3: np.ndarray
    b3: float
    out_min: float
    out_max: float

    @classmethod
    def from_floats(cls, n_in: int, v: np.ndarray, hidden: int = 50) -> "NetTables":
        sizes = [n_in, n_in, n_in * hidden, hidden, hidden * hidden, hidden, hidden, 1, 1, 1]
        if len(v) != sum(sizes):
            raise BenchError(f"nnbench: {len(v)} floats for a {n_in}-input network, expected {sum(sizes)}")
        parts = np.split(v, np.cumsum(sizes)[:-1])
        return cls(n_in=n_in, in_min=parts[0], in_max=parts[1], w1=parts[2].reshape(n_in, hidden), b1=parts[3],
                   w2=parts[4].reshape(hidden, hidden), b2=parts[5], w3=parts[6], b3=float(parts[7][0]),
                   out_min=float(parts[8][0]), out_max=float(parts[9][0]))


def torch_reference(net: NetTables, feats: np.ndarray) -> np.ndarray:
    """The network in PyTorch (float32 nn.Linear/ReLU), with the firmware's input/output scaling and clamp."""
    from harness.optional import require_torch
    torch = require_torch("the M4 network bench's agreement check (PyTorch reference)")
    hidden = net.b1.size
    seq = torch.nn.Sequential(torch.nn.Linear(net.n_in, hidden), torch.nn.ReLU(),
                              torch.nn.Linear(hidden, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 1))
    with torch.no_grad():
        seq[0].weight.copy_(torch.from_numpy(net.w1.T.copy()))
        seq[0].bias.copy_(torch.from_numpy(net.b1.copy()))
        seq[2].weight.copy_(torch.from_numpy(net.w2.T.copy()))
        seq[2].bias.copy_(torch.from_numpy(net.b2.copy()))
        seq[4].weight.copy_(torch.from_numpy(net.w3.reshape(1, -1).copy()))
        seq[4].bias.fill_(net.b3)
        x = (feats.astype(np.float32) - net.in_min) / (net.in_max - net.in_min)
        y = seq(torch.from_numpy(x.astype(np.float32))).numpy()[:, 0].astype(np.float64)
    y = y * (net.out_max - net.out_min) + net.out_min
    return np.clip(y, net.out_min, net.out_max)


class NnBenchClient:
    """Talks to uwb-nnbench.elf (protocol in firmware_sim/stm32/nnbench_main.c)."""

    def __init__(self, link: Any, timeout_s: float = 5.0) -> None:
        self.link = link
        self.timeout_s = timeout_s

    def _read(self, n: int) -> bytes:
        buf = b""
        deadline = time.monotonic() + self.timeout_s
        while len(buf) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BenchError(f"nnbench: {len(buf)} of {n} reply bytes within {self.timeout_s:.0f} s")
            buf += self.link.read(n - len(buf), min(left, 0.1))
        return buf

    def info(self) -> tuple[int, int]:
        self.link.write(b"I")
        r = self._read(5)
        if r[:1] != b"i":
            raise BenchError(f"nnbench: bad info reply {r!r}")
        return r[1], r[2]

    def tables(self, kind: int) -> NetTables | None:
        self.link.write(b"W" + bytes([kind]))
        head = self._read(1)
        if head == b"?":
            return None
        if head != b"w":
            raise BenchError(f"nnbench: bad tables reply {head!r}")
        n_in = self._read(1)[0]
        count = 2 * n_in + 50 * n_in + 50 + 2500 + 50 + 50 + 3
        return NetTables.from_floats(n_in, np.frombuffer(self._read(4 * count), "<f4").copy())

    def predict(self, kind: int, x: np.ndarray) -> tuple[tuple[float, float, float], tuple[int, int, int]]:
        self.link.write(b"P" + bytes([kind]) + np.asarray(x, "<f4").tobytes())
        r = self._read(25)
        if r[:1] != b"p":
            raise BenchError(f"nnbench: bad predict reply {r!r}")
        return struct.unpack("<3f", r[1:13]), struct.unpack("<3I", r[13:25])


def _process_start(elf: Path, log_dir: Path | None) -> Any:
    from harness.device.qemu import QemuOptions, QemuProcess
    log = (log_dir or Path("/tmp")) / f"qemu-nnbench-{time.time_ns()}.log"
    proc = QemuProcess(elf, log, QemuOptions())
    proc.start()
    return proc


def network_kernels(n_inputs: int, seed: int, log_dir: Path | None = None,
                    elf: Path = ELF_NNBENCH, model: str = "shipped") -> list[KernelRow]:
    """The compiled-in networks through the three kernels on the same random inputs (uniform over each
    input's scaling range), against PyTorch on the same weights (dumped from the device). The comparison
    only means something where the output is not clamped and not constant: `unclamped` and `ref_std` say
    how much of it does (the probe model of harness/stm32_build.py is built for that)."""
    from harness.link.qemu_link import QemuPtyLink
    rng = np.random.default_rng(seed)
    rows: list[KernelRow] = []
    proc = _process_start(elf, log_dir)
    try:
        client = NnBenchClient(QemuPtyLink(proc.fd, proc.serial_name or "?"), timeout_s=10.0)
        for kind, kind_name in ((0, "twr"), (1, "tdoa")):
            net = client.tables(kind)
            if net is None:
                continue
            feats = (net.in_min + rng.uniform(0.0, 1.0, (n_inputs, net.n_in)) * (net.in_max - net.in_min))
            feats = feats.astype(np.float32)
            ys = np.zeros((n_inputs, 3))
            costs = np.zeros((n_inputs, 3), np.int64)
            for i in range(n_inputs):
                y, c = client.predict(kind, feats[i])
                ys[i], costs[i] = y, c
            ref = torch_reference(net, feats)
            inside = float(np.mean((ref > net.out_min) & (ref < net.out_max)))
            base = float(np.median(costs[:, 0]))
            for k, name in enumerate(KERNELS):
                med = float(np.median(costs[:, k]))
                rows.append(KernelRow(model=model, kernel=name, kind=kind_name, n_in=net.n_in, n=n_inputs, instructions=med,
                                      speedup=base / med if med else float("inf"),
                                      max_err_torch=float(np.max(np.abs(ys[:, k] - ref))),
                                      unclamped=inside, ref_std=float(np.std(ref))))
    finally:
        proc.stop()
    return rows
