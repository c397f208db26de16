"""The numpy twin restates the firmware core's constants (harness/twin/*.py beside firmware_sim/core/*.[ch]).

The core-vs-twin tests compare outputs, so a constant changed on one side only shows up there as a position
or variance mismatch somewhere in a flight; here it fails by name. Every `#define` of the core that the twin
restates is listed; a C constant or twin attribute that disappears fails too (renamed: update the table).
"""

from __future__ import annotations

import ast
import importlib
import operator
import re

import pytest

from harness.paths import REPO_ROOT

CORE = REPO_ROOT / "firmware_sim" / "core"

#: C name -> (twin module, attribute)
TWIN_OF = {
    "BIAS_NN_OOD_MARGIN": ("features", "OOD_MARGIN"),
    "BIAS_ST_ANCHORS": ("bias_states", "ANCHORS"),
    "BIAS_ST_TAU_S": ("bias_states", "TAU_S"),
    "BIAS_ST_STD": ("bias_states", "STD"),
    "EKF_N": ("ekf", "N"),
    "EKF_GRAVITY": ("ekf", "GRAVITY"),
    "EKF_P_MIN": ("ekf", "P_MIN"),
    "EKF_P_MAX": ("ekf", "P_MAX"),
    "EKF_PREDICT_INTERVAL_US": ("ekf", "PREDICT_INTERVAL_US"),
    "EKF_INIT_STD_VEL": ("ekf", "INIT_STD_VEL"),
    "EKF_INIT_STD_ATT": ("ekf", "INIT_STD_ATT"),
    "EKF_ATT_ERR_MAX": ("ekf", "ATT_ERR_MAX"),
    "EKF_GYRO_NOISE_RP": ("ekf", "GYRO_NOISE_RP"),
    "EKF_GYRO_NOISE_YAW": ("ekf", "GYRO_NOISE_YAW"),
    "GATE_KIN_ANCHORS": ("gates", "MAX_ANCHORS"),
    "GATE_CHI2_REOPEN_US": ("gates", "CHI2_REOPEN_US"),
    "ROBUST_CAUCHY_C": ("gates", "ROBUST_CAUCHY_C"),
    "ROBUST_ITERATIONS": ("gates", "ROBUST_ITERATIONS"),
    "ROBUST_W_MIN": ("gates", "ROBUST_W_MIN"),
    "LPS_TYPE_TDOA2": ("lps_packets", "TYPE_TDOA2"),
    "LPS_TYPE_TDOA3": ("lps_packets", "TYPE_TDOA3"),
    "LPS_LPP_SHORT": ("lps_packets", "LPP_SHORT"),
    "LPS_LPP_POSITION": ("lps_packets", "LPP_POSITION"),
    "LPS_TDOA2_SIZE": ("lps_packets", "TDOA2_SIZE"),
    "LPS_TDOA2_ANCHORS": ("lps_packets", "TDOA2_ANCHORS"),
    "LPS_TDOA3_HEADER": ("lps_packets", "TDOA3_HEADER"),
    "LPS_MAX_REMOTE": ("lps_packets", "MAX_REMOTE"),
    "LPS_SEQ_MASK": ("lps_packets", "SEQ_MASK"),
    "LPS_MAX_COORD": ("lps_packets", "MAX_COORD"),
    "MM_MIN_DISTANCE": ("harness.kinds", "MIN_DISTANCE"),
    "NN_MON_ANCHORS": ("nn_monitor", "ANCHORS"),
    "NN_MON_ALPHA": ("nn_monitor", "ALPHA"),
    "NN_MON_MIN_SAMPLES": ("nn_monitor", "MIN_SAMPLES"),
    "NN_MON_WORSE": ("nn_monitor", "WORSE"),
    "NN_MON_CLIP": ("nn_monitor", "CLIP"),
    "EST_MAX_HEIGHT_STD": ("estimator", "MAX_HEIGHT_STD"),
    "EST_MAX_ABS_POSITION": ("supervisor", "MAX_ABS_POSITION"),
    "EST_GAP_US": ("supervisor", "GAP_US"),
    "TDOA_STORAGE_COUNT": ("tdoa_engine", "STORAGE_COUNT"),
    "TDOA_REMOTE_COUNT": ("tdoa_engine", "REMOTE_COUNT"),
    "TDOA_TOF_COUNT": ("tdoa_engine", "TOF_COUNT"),
    "TDOA_TS_FREQ": ("tdoa_engine", "TS_FREQ"),
    "TDOA_SPEED_OF_LIGHT": ("tdoa_engine", "SPEED_OF_LIGHT"),
    "TDOA_CC_ACCEPTED_NOISE": ("tdoa_engine", "CC_ACCEPTED_NOISE"),
    "TDOA_CC_MAX_DEVIATION": ("tdoa_engine", "CC_MAX_DEVIATION"),
    "TDOA_CC_FILTER": ("tdoa_engine", "CC_FILTER"),
    "TDOA_CC_BUCKET_MAX": ("tdoa_engine", "CC_BUCKET_MAX"),
    "TDOA_REMOTE_VALID_MS": ("tdoa_engine", "REMOTE_VALID_MS"),
    "TDOA_TOF_VALID_MS": ("tdoa_engine", "TOF_VALID_MS"),
    "TDOA_MASK40": ("tdoa_engine", "MASK40"),
}

_DEFINE = re.compile(r"^#define\s+([A-Z][A-Z0-9_]*)\s+((?:(?!/[*/])[^\n])+?)\s*(?:/[*/].*)?$", re.MULTILINE)
_SUFFIX = re.compile(r"\b(0[xX][0-9a-fA-F]+|[0-9][0-9.]*(?:[eE][-+]?[0-9]+)?)(?:[fF]|[uU]?[lL]{0,2})\b")
_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}


def _value(text: str) -> float:
    """A C constant expression of numbers and + - * / (suffixes f, u, ull dropped)."""
    def ev(node: ast.AST) -> float:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return node.value
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -ev(node.operand)
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.left), ev(node.right))
        raise ValueError(f"not a numeric constant: {text!r}")
    return ev(ast.parse(_SUFFIX.sub(r"\1", text), mode="eval").body)


def core_defines() -> dict[str, str]:
    out: dict[str, str] = {}
    for path in sorted([*CORE.glob("*.h"), *CORE.glob("*.c")]):
        out.update(dict(_DEFINE.findall(path.read_text())))
    return out


@pytest.mark.parametrize("c_name", sorted(TWIN_OF))
def test_twin_restates_the_core_constant(c_name: str) -> None:
    defines = core_defines()
    assert c_name in defines, f"{c_name} is no longer defined in firmware_sim/core: update TWIN_OF"
    module, attr = TWIN_OF[c_name]
    twin = getattr(importlib.import_module(module if "." in module else f"harness.twin.{module}"), attr)
    c_value = _value(defines[c_name])
    # float constants are float32 in C ('f' suffix): equal to within its rounding
    assert twin == pytest.approx(c_value, rel=1e-7, abs=0.0), \
        f"{c_name} = {defines[c_name]} in the core, harness.twin.{module}.{attr} = {twin}"


def test_the_parser_reads_the_core_forms() -> None:
    assert _value("(1.0f / 64.0f)") == pytest.approx(1 / 64)
    assert _value("0xFFFFFFFFFFull") == 0xFFFFFFFFFF and _value("10000u") == 10000 and _value("1e-6f") == 1e-6
