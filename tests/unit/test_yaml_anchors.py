"""Anchor and constellation YAML files go through PyYAML: any valid YAML style is accepted, and the
loaded data is validated with the file line of a bad value."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from constellation_yaml import save_constellation_yaml
from harness.flight.arena import ConstellationError, load_constellation
from harness.flight.formats.anchors import load_anchor_yaml, load_anchors
from harness.flight.formats.common import RecordingError
from harness.flight.scenarios import default_anchors

RCV_FLOW = """anchor1:
  - position:
      data: [2.0, 2.0, 1.0]
  - orientation:
      data: [0.0, 0.0, 0.0, 1.0]
anchor2:
  - position:
      data: [-2.0, 2.0, 1.2]
  - orientation:
      data: [0.0, 0.0, 0.7071068, 0.7071068]
"""

# The same anchors in block style, a mapping instead of a list, numbers without `data:`, comments.
RCV_BLOCK = """# surveyed 2024-06-09
anchor1:
  position:
    data:
      - 2.0
      - 2.0
      - 1.0
  orientation: {data: [0.0, 0.0, 0.0, 1.0]}
anchor2:
  - position: [-2.0, 2.0, 1.2]     # metres
  - orientation:
      - 0.0
      - 0.0
      - 0.7071068
      - 0.7071068
"""


def test_rcv_anchor_yaml_in_block_style_equals_flow_style(tmp_path: Path) -> None:
    flow, block = tmp_path / "flow.yaml", tmp_path / "block.yaml"
    flow.write_text(RCV_FLOW)
    block.write_text(RCV_BLOCK)
    a, b = load_anchor_yaml(flow), load_anchor_yaml(block)
    assert list(a.ids) == list(b.ids) == [1, 2]
    assert np.array_equal(a.positions, b.positions)
    assert np.allclose(a.positions[1], [-2.0, 2.0, 1.2])
    assert a.orientations is not None and b.orientations is not None
    assert np.allclose(a.orientations, b.orientations)
    assert np.allclose(b.orientations[1], np.array([0.7071068, 0.0, 0.0, 0.7071068]) / np.sqrt(2 * 0.7071068 ** 2))


@pytest.mark.parametrize("text,line,match", [
    (RCV_BLOCK.replace("      - 1.0\n", "      - one\n"), 4, "expected 3 numbers"),
    (RCV_BLOCK.replace("[-2.0, 2.0, 1.2]", "[-2.0, 2.0]"), 10, "expected 3 numbers"),
    (RCV_BLOCK.replace("[-2.0, 2.0, 1.2]", "[-2.0, .nan, 1.2]"), 10, "finite"),
    (RCV_BLOCK.replace("anchor2:", "anchor1:"), 9, "duplicate key"),
    (RCV_BLOCK.replace("anchor2:", "tag2:"), 9, "unexpected key 'tag2'"),
    (RCV_BLOCK.replace("  orientation: {data:", "  orientation: {data: [1, 2"), 8, "not valid YAML"),
    (RCV_BLOCK.replace("  - position: [-2.0, 2.0, 1.2]     # metres\n", ""), 9, "no position"),
])
def test_rcv_anchor_yaml_errors_name_the_line(tmp_path: Path, text: str, line: int, match: str) -> None:
    p = tmp_path / "anchor.yaml"
    p.write_text(text)
    with pytest.raises(RecordingError, match=match) as info:
        load_anchors(p)
    assert info.value.line == line, str(info.value)
    assert str(p) in str(info.value)


@pytest.mark.parametrize("data, match", [
    (b"anchor1: &a [*a]\n", "recursive alias or nesting too deep"),
    (b"a: " + b"[" * 5000 + b"]" * 5000 + b"\n", "recursive alias or nesting too deep"),
    (b"\xff\xfe\x00garbage", "not a UTF-8 text file"),
])
def test_a_recursive_deep_or_binary_yaml_is_a_named_error(tmp_path: Path, data: bytes, match: str) -> None:
    """A self-referencing alias, 5000 nested lists, a binary file: a RecordingError naming the file (they were a
    RecursionError or UnicodeDecodeError, exit 4)."""
    p = tmp_path / "anchor.yaml"
    p.write_bytes(data)
    with pytest.raises(RecordingError, match=match) as info:
        load_anchors(p)
    assert str(p) in str(info.value)


def test_constellation_yaml_in_block_style(tmp_path: Path) -> None:
    anchors = default_anchors()
    flow = tmp_path / "flow.yaml"
    save_constellation_yaml(anchors, flow)
    block = tmp_path / "block.yaml"
    lines = ["anchors:"]
    for k, i in enumerate(anchors.ids):
        lines += [f"  - id: {int(i)}", "    position:"] + [f"      - {v:.6f}" for v in anchors.positions[k]]
        lines += ["    orientation: [" + ", ".join(f"{v:.9f}" for v in anchors.orientations[k]) + "]"]
    block.write_text("\n".join(lines) + "\n")
    a, b = load_constellation(flow), load_constellation(block)
    assert np.array_equal(a.ids, b.ids) and np.array_equal(a.positions, b.positions)
    assert np.allclose(a.orientations, b.orientations)
    # the rcv_twr reader hands `anchors:` files to the constellation reader
    assert np.array_equal(load_anchors(block).positions, b.positions)


@pytest.mark.parametrize("text,match", [
    ("anchors:\n  - id: 0\n    position: [0, 0]\n", r"c.yaml:3: field position needs 3"),
    ("anchors:\n  - id: 0\n    position:\n      - 0\n      - x\n      - 1\n", r"c.yaml:3: field position must be"),
    ("anchors:\n  - id: zero\n    position: [0, 0, 1]\n", r"c.yaml:2: field id must be an integer"),
    ("anchors:\n  - id: 0\n    position: [0, 0, 1]\n    colour: red\n", r"c.yaml:4: unknown field 'colour'"),
    ("anchors:\n  - id: 0\n    position: [0, 0, 1\n", r"c.yaml:\d+: not valid YAML"),
    ("anchors: []\n", r"c.yaml:1: no anchors"),
])
def test_constellation_yaml_errors_name_the_line(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(ConstellationError, match=match):
        load_constellation(p)
