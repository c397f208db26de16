"""Start-up time of the QEMU target: serial over a unix socket versus the pty recipe (1.2 s settle).

    python -m harness.bench.qemu_start [--starts 6]

Each start is QemuDevice.start() + HELLO (what every test or run pays before its first measurement), on
the shipped STM32 build (make stm32); the two transports alternate so machine load hits both alike.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from harness.device.qemu import DEFAULT_ELF, QemuDevice, QemuOptions

TRANSPORTS = ("socket", "pty")


def start_seconds(elf: Path, serial: str) -> float:
    with tempfile.TemporaryDirectory(prefix="uwb-qemu-start-") as tmp:
        device = QemuDevice(elf, log_dir=tmp, options=QemuOptions(serial=serial))
        t0 = time.monotonic()
        try:
            device.start()
            device.hello(timeout=10.0)
            return time.monotonic() - t0
        finally:
            device.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--starts", type=int, default=6, help="starts per transport")
    ap.add_argument("--elf", type=Path, default=DEFAULT_ELF)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not args.elf.is_file():
        print(f"harness.bench.qemu_start: error: {args.elf} not found: run `make stm32`", file=sys.stderr)
        return 2
    times: dict[str, list[float]] = {t: [] for t in TRANSPORTS}
    for _ in range(max(1, args.starts)):
        for t in TRANSPORTS:
            times[t].append(start_seconds(args.elf, t))
    out = {t: {"median_s": statistics.median(v), "min_s": min(v), "max_s": max(v), "n": len(v)}
           for t, v in times.items()}
    out["saving_s"] = out["pty"]["median_s"] - out["socket"]["median_s"]
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for t in TRANSPORTS:
            print(f"{t:6s} start + HELLO: median {out[t]['median_s']:.3f} s (min {out[t]['min_s']:.3f}, "
                  f"max {out[t]['max_s']:.3f}, n {out[t]['n']})")
        print(f"saving per start: {out['saving_s']:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
