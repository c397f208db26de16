#!/usr/bin/env python3
"""Flash and RAM use of the STM32 firmware, broken down by component, from the GNU ld map file.

    python3 size_report.py --elf ../build/stm32/uwb-fw.elf --map ../build/stm32/uwb-fw.map [--json]

Flash = vector table + code + read-only data + the flash image of .data. RAM = stack reservation +
.data + .bss (no heap). The bias network's share is everything from core/bias_nn.c (code, features and
the const weight tables it includes) plus the M4 kernel (nn_m4.c). Standard library only: runs with
the system python3 from `make size`.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

FLASH_BYTES = 1024 * 1024
RAM_BYTES = 128 * 1024
GOAL_FLASH = 48 * 1024   # issue 24 (was 64 KB, issue 7)
GOAL_RAM = 32 * 1024

FW_DIR = Path(__file__).resolve().parent.parent
NETWORK_OBJECTS = {"bias_nn.o", "nn_m4.o"}
FLASH_SECTIONS = (".isr_vector", ".text", ".rodata", ".ARM.extab", ".ARM.exidx")
RAM_SECTIONS = (".stack", ".data", ".bss")

_OUT_RE = re.compile(r"^(\.[\w.]+)\s+0x([0-9a-f]+)\s+0x([0-9a-f]+)")
_FILL_RE = re.compile(r"^\s+\*fill\*\s+0x[0-9a-f]+\s+0x([0-9a-f]+)")
_IN_RE = re.compile(r"^\s+(\S+)?\s*0x([0-9a-f]+)\s+0x([0-9a-f]+)\s+(\S.*)$")


@dataclass
class SizeReport:
    flash: int
    ram: int
    sections: dict[str, int]
    components: dict[str, dict[str, int]]     # component -> {"flash": B, "ram": B}
    network_flash: int
    network_weights: int                      # const float tables (rodata) of the network
    network_code: int
    network_ram: int
    stack_reserved: int
    goals: dict[str, int] = field(default_factory=lambda: {"flash": GOAL_FLASH, "ram": GOAL_RAM})

    @property
    def ok(self) -> bool:
        return self.flash <= GOAL_FLASH and self.ram <= GOAL_RAM


def _component(origin: str, core: set[str], proto: set[str], app: set[str]) -> str:
    if origin == "*fill*" or origin.startswith("linker stubs"):
        return "alignment"
    m = re.search(r"lib(m|c|gcc|c_nano|m_nano)\.a", origin)
    if m:
        return {"m": "libm", "m_nano": "libm", "c": "libc", "c_nano": "libc", "gcc": "libgcc"}[m.group(1)]
    name = Path(origin.split("(")[0]).name
    if name in NETWORK_OBJECTS:
        return "network"
    if name in core:
        return "estimator core"
    if name in proto:
        return "protocol"
    if name in app:
        return "app"
    return "board"


def _object_groups(fw_dir: Path) -> tuple[set[str], set[str], set[str]]:
    """The object files of the estimator core (the network's aside), the protocol and the app."""
    core = {p.with_suffix(".o").name for p in (fw_dir / "core").glob("*.c")} - NETWORK_OBJECTS
    proto = {p.with_suffix(".o").name for p in (fw_dir / "proto").glob("*.c")}
    app = {p.with_suffix(".o").name for p in (fw_dir / "app").glob("*.c")}
    return core, proto, app


def parse_map(map_path: Path, fw_dir: Path = FW_DIR) -> SizeReport:
    core, proto, app = _object_groups(fw_dir)
    text = map_path.read_text(errors="replace")
    start = text.find("Linker script and memory map")
    if start < 0:
        raise ValueError(f"{map_path}: not a GNU ld map file")
    sections: dict[str, int] = {}
    comps: dict[str, dict[str, int]] = {}
    net_weights = net_code = 0
    current: str | None = None
    pending: str | None = None  # input-section name printed alone on its line
    for line in text[start:].splitlines():
        mo = _OUT_RE.match(line)
        if mo:
            current = mo.group(1)
            sections[current] = int(mo.group(3), 16)
            pending = None
            continue
        if current is None or current not in FLASH_SECTIONS + RAM_SECTIONS:
            continue
        mf = _FILL_RE.match(line)
        if mf and current != ".stack":
            slot = comps.setdefault("alignment", {"flash": 0, "ram": 0})
            slot["flash" if current in FLASH_SECTIONS else "ram"] += int(mf.group(1), 16)
            continue
        if re.match(r"^ (\.\S+|COMMON)\s*$", line):
            pending = line.strip()
            continue
        mi = _IN_RE.match(line)
        if not mi:
            continue
        name = mi.group(1) or pending or ""
        pending = None
        if name.startswith("0x"):
            continue
        size = int(mi.group(3), 16)
        origin = mi.group(4).strip()
        if size == 0 or not (name.startswith(".") or name == "COMMON"):
            continue
        comp = _component(origin, core, proto, app)
        kind = "flash" if current in FLASH_SECTIONS else "ram"
        slot = comps.setdefault(comp, {"flash": 0, "ram": 0})
        slot[kind] += size
        if current == ".data":  # initialised data also occupies flash (its load image)
            slot["flash"] += size
        if comp == "network" and kind == "flash":
            if current == ".rodata":
                net_weights += size
            else:
                net_code += size
    if sections.get(".stack"):
        comps["stack (reserved)"] = {"flash": 0, "ram": sections[".stack"]}
    flash = sum(sections.get(s, 0) for s in FLASH_SECTIONS) + sections.get(".data", 0)
    ram = sum(sections.get(s, 0) for s in RAM_SECTIONS)
    net = comps.get("network", {"flash": 0, "ram": 0})
    return SizeReport(flash=flash, ram=ram, sections={k: v for k, v in sections.items()
                                                       if k in FLASH_SECTIONS + RAM_SECTIONS},
                      components=comps, network_flash=net["flash"], network_weights=net_weights,
                      network_code=net_code, network_ram=net["ram"], stack_reserved=sections.get(".stack", 0))


def _pct(a: int, b: int) -> str:
    return f"{100.0 * a / b:.1f}%"


def format_report(r: SizeReport) -> str:
    ok = lambda v, g: "OK" if v <= g else "OVER"  # noqa: E731
    lines = [
        f"flash {r.flash:>7,} B  ({_pct(r.flash, FLASH_BYTES)} of 1 MiB; goal <= {GOAL_FLASH:,} B: {ok(r.flash, GOAL_FLASH)})",
        f"RAM   {r.ram:>7,} B  ({_pct(r.ram, RAM_BYTES)} of 128 KiB; goal <= {GOAL_RAM:,} B: {ok(r.ram, GOAL_RAM)})"
        f"  = stack {r.stack_reserved:,} + .data {r.sections.get('.data', 0):,} + .bss {r.sections.get('.bss', 0):,}",
        f"bias network: flash {r.network_flash:,} B = {_pct(r.network_flash, r.flash)} of the firmware's flash"
        f" (weights {r.network_weights:,} B, code {r.network_code:,} B), RAM {r.network_ram:,} B",
        "by component        flash      RAM",
    ]
    for comp, v in sorted(r.components.items(), key=lambda kv: -kv[1]["flash"]):
        lines.append(f"  {comp:<15} {v['flash']:>8,} {v['ram']:>8,}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elf", type=Path, required=True)
    ap.add_argument("--map", type=Path, required=True)
    ap.add_argument("--size-tool", default="arm-none-eabi-size")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    report = parse_map(args.map)
    # Cross-check the map total against the ELF (arm-none-eabi-size -A).
    try:
        out = subprocess.run([args.size_tool, "-A", str(args.elf)], capture_output=True, text=True,
                             timeout=30, check=True).stdout
        elf_sections = {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\.\S+)\s+(\d+)", out, re.M)}
        elf_flash = sum(elf_sections.get(s, 0) for s in FLASH_SECTIONS) + elf_sections.get(".data", 0)
        if elf_flash != report.flash:
            print(f"warning: map flash {report.flash} != ELF flash {elf_flash}", file=sys.stderr)
    except (OSError, subprocess.SubprocessError) as exc:
        print(f"warning: {args.size_tool} failed: {exc}", file=sys.stderr)
    if args.json:
        d = asdict(report)
        d["ok"] = report.ok
        print(json.dumps(d, indent=2))
    else:
        print(format_report(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
