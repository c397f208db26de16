"""Protocol enums are defined once (protocol/messages.toml): Python takes them from the generated module,
never re-types their values; the C core's own copies are pinned to the generated header by static asserts
(firmware_sim/app/proto_checks.h), one per constant, and a drift fails the build."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from harness import config
from harness.flight import data as flight_model
from harness.twin import estimator as twin_estimator
from harness.twin import features
from protocol.messages import MAX_ANCHORS, EkfMode, Layout, MeasKind, ResultFlag, Stage, Status
from protocol.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_sim"
CHECKS = FW / "app" / "proto_checks.h"
#: Constants of the C core that mirror a protocol enum (core headers do not include uwb_msgs.h).
CORE_MIRRORS = re.compile(r"\b(EST_(?:ERR|FLAG|MODE|STAGE)_\w+|EST_ACCEPTED|EST_REJECTED_\w+|BIAS_LAYOUT_\w+|"
                          r"TDOA_DROP_\w+|CTL_(?:MODE|FLAG|ERR)_\w+|PLATFORM_COST_\w+|ESTIMATOR_MAX_ANCHORS)\b")
#: Abbreviations a constant's prefix may use for its enum (ERR_TIME_BACKWARDS is error_code TIME_BACKWARDS).
PREFIX_ALIASES = {"err": "error", "kind": "kind", "flag": "flag"}


def _retyped(tree: ast.AST, members: dict[str, set[tuple[str, int]]]) -> list[tuple[int, str, str]]:
    """(line, name, enum) of `NAME = <int literal>` where NAME is an enum member (bare, or behind a prefix
    naming its enum: STATUS_ACCEPTED, KIND_TWR, LAYOUT_TWR_POS) with that member's value."""
    found = []
    # members of a host-side enum class (flight/data.py Source.IMU) are that enum's own values, not retyped ones
    own = {id(n) for c in ast.walk(tree) if isinstance(c, ast.ClassDef)
           and any(getattr(b, "id", getattr(b, "attr", "")).endswith("Enum") for b in c.bases) for n in c.body}
    for node in ast.walk(tree):
        if id(node) in own:
            continue
        if not (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and isinstance(node.value, ast.Constant) and type(node.value.value) is int):
            continue
        name = node.targets[0].id
        for member, owners in members.items():
            if name != member and not name.endswith("_" + member):
                continue
            prefix = name[:-len(member)].rstrip("_").lower()
            for enum_name, value in owners:
                words = enum_name.split("_")
                last = prefix.rpartition("_")[2]
                if value == node.value.value and (not prefix or PREFIX_ALIASES.get(last, last) in words):
                    found.append((node.lineno, name, enum_name))
    return found


def _members() -> dict[str, set[tuple[str, int]]]:
    members: dict[str, set[tuple[str, int]]] = {}
    for enum in load_spec().enums:
        for member, value in enum.values:
            members.setdefault(member, set()).add((enum.name, value))
    return members


def test_the_retype_detector_finds_what_it_should() -> None:
    src = ("STATUS_ACCEPTED = 0\nKIND_TWR = 1\nACCEPTED = 0\nERR_TIME_BACKWARDS = 5\nLAYOUT_TDOA_POS = 4\n"
           "LPP_POSITION = 1\nKIND_TWR_X = 1\nSTATUS_ACCEPTED_COUNT = 7\nMODE_IMU = int(EkfMode.IMU)\n")
    found = [name for _, name, _ in _retyped(ast.parse(src), _members())]
    assert found == ["STATUS_ACCEPTED", "KIND_TWR", "ACCEPTED", "ERR_TIME_BACKWARDS", "LAYOUT_TDOA_POS"]


def test_no_python_module_retypes_a_protocol_enum_value() -> None:
    members = _members()
    bad = [f"{f.relative_to(ROOT)}:{line} {name} (enum {enum})"
           for pkg in ("harness", "protocol") for f in sorted((ROOT / pkg).rglob("*.py")) if f.name != "_generated.py"
           for line, name, enum in _retyped(ast.parse(f.read_text()), members)]
    assert not bad, "take these from protocol.messages: " + ", ".join(bad)


def test_python_names_are_the_generated_values_as_plain_ints() -> None:
    pairs = [(config.MODE_IMU, EkfMode.IMU), (config.MODE_UWB_ONLY, EkfMode.UWB_ONLY),
             (config.STAGE_BIAS_NN, Stage.BIAS_NN), (config.STAGE_KINEMATIC_GATE, Stage.KINEMATIC_GATE),
             (config.STAGE_CHI2_GATE, Stage.CHI2_GATE), (config.STAGE_NN_STD, Stage.NN_STD),
             (config.STAGE_ROBUST_UPDATE, Stage.ROBUST_UPDATE),
             (flight_model.KIND_TWR, MeasKind.TWR), (flight_model.KIND_TDOA, MeasKind.TDOA),
             (features.LAYOUT_NONE, Layout.NONE), (features.LAYOUT_TDOA_POS, Layout.TDOA_POS),
             (twin_estimator.ACCEPTED, Status.ACCEPTED), (twin_estimator.REJECTED_GEOMETRY, Status.REJECTED_GEOMETRY),
             (twin_estimator.FLAG_HEIGHT_FUSED, ResultFlag.HEIGHT_FUSED), (twin_estimator.MAX_ANCHORS, MAX_ANCHORS)]
    for ours, generated in pairs:
        assert ours == generated and type(ours) is int     # plain ints: JSON, numpy and f-strings unchanged


def test_every_core_mirror_of_a_protocol_value_has_a_static_assert() -> None:
    core = set()
    for header in sorted((FW / "core").glob("*.h")):
        core |= set(CORE_MIRRORS.findall(header.read_text()))
    checks = CHECKS.read_text()
    asserted = set(re.findall(r"UWB_SAME\(\w+, (\w+), (\w+)\);", checks))
    assert len(core) >= 40
    missing = sorted(core - {c for c, _ in asserted})
    assert not missing, f"add a UWB_SAME line to {CHECKS.relative_to(ROOT)} for: {', '.join(missing)}"
    header = (FW / "proto" / "uwb_msgs.h").read_text()
    assert all(re.search(rf"\b{p}\b", header) for _, p in asserted)    # every protocol side exists


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_a_drifted_core_value_fails_the_build(tmp_path: Path) -> None:
    def compiles(core_dir: Path) -> subprocess.CompletedProcess[str]:
        src = tmp_path / "check.c"
        src.write_text('#include "proto_checks.h"\nint uwb_checks_compiled(void);\nint uwb_checks_compiled(void) '
                       '{ return 1; }\n')
        return subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-fsyntax-only", f"-I{core_dir}",
                               f"-I{FW / 'proto'}", f"-I{FW / 'app'}", str(src)],
                              capture_output=True, text=True, timeout=60)

    assert compiles(FW / "core").returncode == 0
    drifted = tmp_path / "core"
    shutil.copytree(FW / "core", drifted)
    h = drifted / "estimator.h"
    h.write_text(h.read_text().replace("EST_STAGE_NN_STD = 8", "EST_STAGE_NN_STD = 32"))
    out = compiles(drifted)
    assert out.returncode != 0 and "uwb_check_stage_nn_std" in out.stderr
