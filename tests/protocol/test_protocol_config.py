"""The estimator configuration is defined once, on the CONFIG fields of protocol/messages.toml.

The generator makes the Python dataclass and its validation and the C struct, defaults and validation
from it. Here: Python and the C build agree on every field's default and bounds (asked of the compiled
C through tools/replay_core), and adding a field takes one edit in messages.toml: the generated Python,
the C defaults and checks, the firmware's CONFIG handling and the replay tool all take it up.
"""

from __future__ import annotations

import importlib.util
import math
import shutil
import struct
import subprocess
import sys
from dataclasses import asdict, fields, replace
from pathlib import Path
from types import ModuleType

import pytest

from harness.config import ConfigError, EstimatorConfig
from protocol import FrameDecoder, encode_frame, generate
from protocol import messages as m
from protocol.config_check import ConfigField, as_float32
from protocol.spec import SpecError, load_spec

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware_sim"
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wpointer-arith", "-Wstrict-prototypes",
          "-Wmissing-prototypes", "-Icore", "-Iproto", "-Iapp", "-Imodels", "-O0", "-D_POSIX_C_SOURCE=200809L"]
#: The field the one-edit test adds (appended to CONFIG's fields in a copy of messages.toml).
EXTRA = ('  ["gate_test_k", "f32", "a field added by tests/protocol/test_protocol_config.py", '
         '{unit = "m", default = 1.5, gt = 0, le = 4}],\n')


def _cc() -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    return cc


def _build_replay(fw: Path, out: Path) -> Path:
    subprocess.run([_cc(), *CFLAGS, "-o", str(out), *sorted(str(p) for p in (fw / "core").glob("*.c")),
                    "host/platform_host.c", "tools/replay_core.c", "-lm"], cwd=fw, check=True,
                   capture_output=True, text=True)
    return out


@pytest.fixture(scope="module")
def replay(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _build_replay(FW, tmp_path_factory.mktemp("cfg") / "replay_core")


def _c_defaults(exe: Path) -> dict[str, float]:
    out = subprocess.run([str(exe), "--fields"], capture_output=True, text=True, check=True).stdout
    # %.9g identifies a float32 exactly: round the text back to float32
    return {name: as_float32(float(value)) for _, name, value in (line.split() for line in out.splitlines())}


def _c_valid(exe: Path, probes: list[dict[str, float | int]]) -> list[bool]:
    """estimator_config_valid() of the defaults with each probe's fields changed."""
    lines = "".join("V " + " ".join(f"{k}={v!r}" for k, v in p.items()) + "\n" for p in probes)
    out = subprocess.run([str(exe), "--no-model"], input=lines, capture_output=True, text=True, check=True).stdout
    return [line == "V 1" for line in out.splitlines() if line.startswith("V ")]


def _probes(f: ConfigField) -> list[float | int]:
    """Values at and around every bound of f, plus non-finite ones for floats."""
    if f.wire != "f32":
        return list(range(256))
    out: list[float | int] = [math.nan, math.inf, -math.inf, f.default, -1e30, 1e30]
    for bound in (f.ge, f.gt, f.le, f.lt):
        if bound is not None:
            below = struct.unpack("<f", struct.pack("<f", bound))[0]
            out += [bound, math.nextafter(below, -math.inf), math.nextafter(below, math.inf), bound - 1e-3,
                    bound + 1e-3]
    return out


def _py_valid(cfg: EstimatorConfig) -> bool:
    try:
        cfg.validate()
    except ConfigError:
        return False
    return True


# ----------------------------------------------------------------------- Python and C agree
def test_python_and_c_have_the_same_fields_and_defaults(replay: Path) -> None:
    c = _c_defaults(replay)
    py = asdict(EstimatorConfig())
    assert list(c) == list(py), "field order differs between the C table and the dataclass"
    for name, value in py.items():
        assert c[name] == as_float32(value), f"default of {name}: C {c[name]}, Python {value}"
    assert [f.name for f in m.CONFIG_FIELDS if not f.control] == list(py)


def test_python_and_c_accept_and_refuse_the_same_values(replay: Path) -> None:
    probes: list[dict[str, float | int]] = []
    for f in m.CONFIG_FIELDS:
        if not f.control:
            probes += [{f.name: v} for v in _probes(f)]
    c = _c_valid(replay, probes)
    py = [_py_valid(replace(EstimatorConfig(), **p)) for p in probes]
    assert len(c) == len(probes)
    differ = [(p, py_ok, c_ok) for p, py_ok, c_ok in zip(probes, py, c) if py_ok != c_ok]
    assert not differ, f"Python and C disagree (probe, Python, C): {differ[:5]}"
    assert 0 < sum(c) < len(c)    # the probes hit both sides of the bounds


def test_validation_names_the_field_and_its_bound() -> None:
    with pytest.raises(ConfigError, match=r"std_twr must be > 0 m, got 0.0"):
        EstimatorConfig(std_twr=0.0).validate()
    with pytest.raises(ConfigError, match=r"mode must be one of IMU=0, UWB_ONLY=1, IMU_THRUST=2, got 3"):
        EstimatorConfig(mode=3).validate()
    with pytest.raises(ConfigError, match=r"stages has unknown bits: 0x80"):
        EstimatorConfig(stages=0x87).validate()
    with pytest.raises(ConfigError, match=r"sup_margin must be >= 0 m"):
        EstimatorConfig(sup_margin=-1.0).validate()
    with pytest.raises(ConfigError, match=r"does not fit the device's 32-bit float"):
        EstimatorConfig(init_x=1e39).validate()
    with pytest.raises(ConfigError, match=r"must be > 0 m, got 1e-50"):    # 0 once rounded to float32
        EstimatorConfig(init_std_xy=1e-50).validate()


def test_the_message_carries_every_field() -> None:
    cfg = EstimatorConfig(std_twr=0.3, stages=3).with_init(1.0, 2.0, 3.0)
    msg = cfg.to_message(reset=0)
    assert isinstance(msg, m.Config) and msg.reset == 0 and msg.tdoa_match == 0   # AUTO (was the reserved byte)
    assert {k: getattr(msg, k) for k in asdict(cfg)} == asdict(cfg)


def test_spec_refuses_a_default_outside_its_bounds(tmp_path: Path) -> None:
    text = (ROOT / "protocol" / "messages.toml").read_text()
    bad = tmp_path / "messages.toml"
    bad.write_text(text.replace('{unit = "m", default = 0.25, gt = 0}', '{unit = "m", default = 0.0, gt = 0}'))
    with pytest.raises(SpecError, match="std_twr: default 0.0 outside its bounds"):
        load_spec(bad)
    bad.write_text(text.replace('default = 0.25, gt = 0', 'default = 0.25, gt = 0, min = 1'))
    with pytest.raises(SpecError, match="unknown attribute"):
        load_spec(bad)


# ------------------------------------------------------------------------ adding a field
def _with_extra_field(tmp: Path) -> Path:
    """A copy of the firmware sources and of messages.toml with EXTRA appended to CONFIG, regenerated."""
    text = (ROOT / "protocol" / "messages.toml").read_text()
    start = text.index('name = "CONFIG"')
    end = text.index("\n]\n", start) + 1
    (tmp / "protocol").mkdir()
    toml = tmp / "protocol" / "messages.toml"
    toml.write_text(text[:end] + EXTRA + text[end:])
    for sub in ("core", "proto", "app", "host", "models", "tools", "tests"):
        shutil.copytree(FW / sub, tmp / "firmware_sim" / sub)
    for path, generated in generate.outputs(load_spec(toml), root=tmp).items():
        path.write_text(generated)
    return tmp


def _load(path: Path, name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module          # dataclasses look the module up while building the classes
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[name]
    return module


def test_adding_a_field_is_one_edit_in_messages_toml(tmp_path: Path) -> None:
    tree = _with_extra_field(tmp_path)
    fw = tree / "firmware_sim"

    # Python: the dataclass has it with its default; validate() applies its bounds; the message carries it.
    gen = _load(tree / "protocol" / "_generated.py", "_generated_extra")
    cfg = gen.EstimatorConfigBase()
    assert cfg.gate_test_k == 1.5 and [f.name for f in fields(cfg)][-1] == "gate_test_k"
    for bad in (0.0, 4.5, math.nan):
        with pytest.raises(gen.ConfigError, match="gate_test_k"):
            replace(cfg, gate_test_k=bad).validate()
    replace(cfg, gate_test_k=4.0).validate()
    msg = replace(cfg, gate_test_k=2.5).to_message(reset=1)
    assert msg.gate_test_k == 2.5 and gen.Config.SIZE == m.Config.SIZE + 4

    # C: struct, defaults and checks (through the replay tool, untouched) ...
    exe = _build_replay(fw, tmp_path / "replay_extra")
    assert _c_defaults(exe)["gate_test_k"] == 1.5
    assert _c_valid(exe, [{"gate_test_k": v} for v in (0.0, 1e-3, 4.0, 4.001, math.inf)]) == \
        [False, True, True, False, False]

    # ... and the firmware (untouched app/) refuses a CONFIG whose new field is out of range.
    fw_exe = tmp_path / "uwb-fw-extra"
    subprocess.run([_cc(), *CFLAGS, "-o", str(fw_exe), *sorted(str(p) for p in fw.glob("core/*.c")),
                    *sorted(str(p) for p in fw.glob("proto/*.c")), *sorted(str(p) for p in fw.glob("app/*.c")),
                    "host/main_host.c", "host/platform_host.c", "-lm"], cwd=fw, check=True, capture_output=True,
                   text=True)
    frames = (encode_frame(cfg.to_message(), 0) + encode_frame(replace(cfg, gate_test_k=9.0).to_message(), 1)
              + encode_frame(m.StatsReq(), 2))
    out = subprocess.run([str(fw_exe), "--stdio"], input=frames, capture_output=True, timeout=30).stdout
    replies = [f.msg for f in FrameDecoder().feed(out)]
    errors = [r for r in replies if isinstance(r, m.Error)]
    assert [(e.code, e.msg_seq) for e in errors] == [(int(m.ErrorCode.BAD_CONFIG), 1)]
    stats = [r for r in replies if isinstance(r, m.Stats)]
    assert len(stats) == 1 and stats[0].bad_configs == 1 and stats[0].bad_lengths == 0
