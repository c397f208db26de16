"""A constellation written as the YAML file harness/flight/arena.py `load_constellation` reads (flow style,
one anchor a line), for the round-trip tests (test_simulator.py, test_yaml_anchors.py)."""

from __future__ import annotations

from pathlib import Path

from harness.flight.data import Anchors


def save_constellation_yaml(anchors: Anchors, path: Path | str) -> None:
    lines = ["anchors:"]
    for k, i in enumerate(anchors.ids):
        p = ", ".join(f"{v:.6f}" for v in anchors.positions[k])
        entry = f"  - {{id: {int(i)}, position: [{p}]"
        if anchors.orientations is not None:
            entry += ", orientation: [" + ", ".join(f"{v:.9f}" for v in anchors.orientations[k]) + "]"
        lines.append(entry + "}")
    Path(path).write_text("\n".join(lines) + "\n")
