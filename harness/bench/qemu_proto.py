"""`make bench` (QEMU part), the protocol path: instructions per frame on the STM32 build under QEMU.

uwb-protobench.elf (firmware_sim/stm32/protobench_main.c) builds an IMU frame (41 bytes on the wire, ~950 per
flight second), a TDoA frame and a RESULT (146 bytes, one per measurement) in the guest and times, with TIM2
under `-icount shift=0` (exact guest instructions, identical from run to run):

  receive  byte-wise   frame_rx_push per byte + cobs_decode + uwb_body_decode (the receiver before the block API)
  receive  block       frame_rx_feed (what firmware_feed runs) + uwb_body_decode in its sink
  send     two copies  uwb_body_encode + cobs_encode + delimiter
  send     in place    uwb_frame_encode (what fw_send_msg runs)

    python -m harness.bench.qemu_proto [--json] [--no-build]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

from harness.bench.qemu_nn import BenchError
from harness.paths import DEFAULT_STM32_ELF

ELF_PROTOBENCH = DEFAULT_STM32_ELF.parent / "uwb-protobench.elf"
TIMEOUT_S = 30.0
#: (path in the guest's output, label): the baseline of each pair first
PAIRS = ((("rx_bytes", "rx_block"), "receive"), (("tx_copy", "tx_frame"), "send"))
LABELS = {"rx_bytes": "byte-wise", "rx_block": "block", "tx_copy": "two copies", "tx_frame": "in place"}


@dataclass(frozen=True)
class ProtoRow:
    path: str          # rx_bytes | rx_block | tx_copy | tx_frame
    message: str       # imu | tdoa | result
    instructions: int


def qemu_command(elf: Path) -> list[str]:
    return ["qemu-system-arm", "-M", "netduinoplus2", "-display", "none", "-nodefaults",
            "-semihosting-config", "enable=on,target=native", "-icount", "shift=0,align=off", "-kernel", str(elf)]


def parse(text: str) -> list[ProtoRow]:
    """The guest's lines `<path> <message> <instructions>`, ended by `ok`; a `FAIL` line is a BenchError."""
    rows: list[ProtoRow] = []
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    for ln in lines:
        parts = ln.split()
        if parts[0] == "FAIL":
            raise BenchError(f"protobench: a path did not give back its message: {ln}")
        if len(parts) == 3 and parts[2].isdigit():
            rows.append(ProtoRow(parts[0], parts[1], int(parts[2])))
    if "ok" not in lines or not rows:
        raise BenchError(f"protobench: incomplete output: {text[-200:]!r}")
    return rows


def run(elf: Path = ELF_PROTOBENCH) -> list[ProtoRow]:
    try:
        done = subprocess.run(qemu_command(elf), capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired as exc:
        raise BenchError(f"protobench: no answer from QEMU within {TIMEOUT_S:.0f} s") from exc
    if done.returncode != 0:
        raise BenchError(f"protobench: QEMU exited with {done.returncode}: {done.stderr.strip()[-200:]}")
    return parse(done.stdout + done.stderr)  # the semihosting console is QEMU's stderr under -nodefaults


def report(rows: list[ProtoRow]) -> list[str]:
    by = {(r.path, r.message): r.instructions for r in rows}
    out = ["Protocol path per frame, STM32F405 build under QEMU (guest instructions, exact):"]
    for (base, new), what in PAIRS:
        for msg in sorted({m for p, m in by if p == base}):
            b, n = by[(base, msg)], by.get((new, msg))
            if n is None:
                continue
            out.append(f"  {what:7s} {msg:6s}  {LABELS[base]:10s} {b:5d}  ->  {LABELS[new]:8s} {n:5d}"
                       f"   ({b / n:.2f}x, {b - n} fewer)")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-build", action="store_true", help="use the existing uwb-protobench.elf")
    ap.add_argument("--elf", type=Path, default=ELF_PROTOBENCH)
    args = ap.parse_args(argv)
    if not args.no_build:
        from harness.stm32_build import build_stm32, ensure_tools
        ensure_tools()
        build_stm32(("protobench",))
    if not args.elf.is_file():
        print(f"harness.bench.qemu_proto: error: {args.elf} not found: run `make stm32`", file=sys.stderr)
        return 2
    try:
        rows = run(args.elf)
    except BenchError as exc:
        print(f"harness.bench.qemu_proto: error: {exc}", file=sys.stderr)
        return 3
    print(json.dumps([asdict(r) for r in rows], indent=2) if args.json else "\n".join(report(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
