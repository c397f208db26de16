"""Load protocol/messages.toml (the single definition of the wire format) into typed objects."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

SPEC_PATH = Path(__file__).with_name("messages.toml")

# wire type -> (struct code, byte size, C type, numpy dtype)
SCALARS: dict[str, tuple[str, int, str, str]] = {
    "u8": ("B", 1, "uint8_t", "u1"),
    "u16": ("H", 2, "uint16_t", "<u2"),
    "u32": ("I", 4, "uint32_t", "<u4"),
    "u64": ("Q", 8, "uint64_t", "<u8"),
    "f32": ("f", 4, "float", "<f4"),
}

HEADER_SIZE = 3  # type u8 + seq u16
CRC_SIZE = 4


class SpecError(ValueError):
    """messages.toml is inconsistent."""


#: Keys a field's attribute table may hold (the CONFIG fields: docs/ARCHITECTURE.md, "Configuration").
FIELD_ATTRS = frozenset({"default", "ge", "gt", "le", "lt", "unit", "enum", "flags", "control"})


@dataclass(frozen=True)
class FieldSpec:
    """One field. The optional attributes (a table after the doc in messages.toml) carry the default and
    the bounds the device enforces: ge / gt / le / lt (inclusive / exclusive), `enum` (the value must be
    one of that enum's), `flags` (only that enum's bits), `control` (a field of the message itself, e.g.
    CONFIG.reset, not of the configuration it carries)."""

    name: str
    wire: str          # u8 u16 u32 u64 f32 bytesN
    doc: str = ""
    default: float | int | None = None
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    unit: str = ""
    enum: str | None = None
    flags: str | None = None
    control: bool = False

    @property
    def is_bytes(self) -> bool:
        return self.wire.startswith("bytes")

    @property
    def size(self) -> int:
        if self.is_bytes:
            return int(self.wire[5:])
        return SCALARS[self.wire][1]

    @property
    def struct_code(self) -> str:
        return f"{self.size}s" if self.is_bytes else SCALARS[self.wire][0]

    @property
    def numpy_dtype(self) -> str:
        return f"S{self.size}" if self.is_bytes else SCALARS[self.wire][3]


@dataclass(frozen=True)
class MessageSpec:
    name: str          # e.g. "HELLO_REPLY"
    msg_id: int
    direction: str     # "to_device" | "to_host"
    doc: str
    fields: tuple[FieldSpec, ...]
    meas_kind: str | None = None   # a measurement message: its member of enum meas_kind (answered by RESULT)

    @property
    def class_name(self) -> str:
        return "".join(part.capitalize() for part in self.name.split("_"))

    @property
    def c_name(self) -> str:
        return self.name.lower()

    @property
    def payload_size(self) -> int:
        return sum(f.size for f in self.fields)

    @property
    def struct_format(self) -> str:
        return "<" + "".join(f.struct_code for f in self.fields)


@dataclass(frozen=True)
class EnumSpec:
    name: str
    doc: str
    values: tuple[tuple[str, int], ...]

    @property
    def class_name(self) -> str:
        return "".join(part.capitalize() for part in self.name.split("_"))


@dataclass(frozen=True)
class ProtocolSpec:
    version: int
    max_body: int
    crc: str
    max_anchors: int
    enums: tuple[EnumSpec, ...]
    messages: tuple[MessageSpec, ...]

    def enum(self, name: str) -> EnumSpec:
        for e in self.enums:
            if e.name == name:
                return e
        raise SpecError(f"no enum {name!r}")

    def message(self, name: str) -> MessageSpec:
        for m in self.messages:
            if m.name == name:
                return m
        raise SpecError(f"no message {name!r}")


#: The message whose non-control fields are the estimator configuration (EstimatorConfig, estimator_config_t).
CONFIG_MESSAGE = "CONFIG"


def _enum_value(enums: dict[str, EnumSpec], owner: str, text: str, bits: bool) -> int:
    """An enum default written by name: "IMU", or for flags "A|B" (empty: 0)."""
    values = dict(enums[owner].values)
    names = [n.strip() for n in text.split("|") if n.strip()] if bits else [text]
    unknown = [n for n in names if n not in values]
    if unknown:
        raise SpecError(f"{owner}: no member {unknown[0]!r}")
    out = 0
    for n in names:
        out |= values[n]
    return out


def _field(msg: str, entry: list, enums: dict[str, EnumSpec]) -> FieldSpec:  # type: ignore[type-arg]
    """[name, wire, doc?, {attributes}?] -> FieldSpec, attributes checked."""
    fname, wire = entry[0], entry[1]
    where = f"{msg}.{fname}"
    if wire not in SCALARS and not (wire.startswith("bytes") and wire[5:].isdigit()):
        raise SpecError(f"{where}: unknown wire type {wire!r}")
    doc = next((e for e in entry[2:] if isinstance(e, str)), "")
    attrs = next((e for e in entry[2:] if isinstance(e, dict)), {})
    unknown = set(attrs) - FIELD_ATTRS
    if unknown:
        raise SpecError(f"{where}: unknown attribute(s) {sorted(unknown)}")
    owner = attrs.get("enum") or attrs.get("flags")
    if owner is not None and owner not in enums:
        raise SpecError(f"{where}: no enum {owner!r}")
    default = attrs.get("default")
    if isinstance(default, str):
        if owner is None:
            raise SpecError(f"{where}: a default by name needs `enum` or `flags`")
        default = _enum_value(enums, owner, default, bits="flags" in attrs)
    if default is not None:
        default = float(default) if wire == "f32" else int(default)
    bounds = {k: (float(attrs[k]) if k in attrs else None) for k in ("ge", "gt", "le", "lt")}
    return FieldSpec(fname, wire, doc, default=default, unit=str(attrs.get("unit", "")), enum=attrs.get("enum"),
                     flags=attrs.get("flags"), control=bool(attrs.get("control", False)), **bounds)


def _check_config(msg: MessageSpec, enums: dict[str, EnumSpec]) -> None:
    """Every CONFIG field has a default its bounds accept (the generated defaults must be valid)."""
    for f in msg.fields:
        if f.default is None:
            raise SpecError(f"{msg.name}.{f.name}: needs a default")
        if f.is_bytes or (f.wire != "f32" and f.wire != "u8"):
            raise SpecError(f"{msg.name}.{f.name}: configuration fields are u8 or f32")
        d = f.default
        if ((f.ge is not None and not d >= f.ge) or (f.gt is not None and not d > f.gt)
                or (f.le is not None and not d <= f.le) or (f.lt is not None and not d < f.lt)):
            raise SpecError(f"{msg.name}.{f.name}: default {d} outside its bounds")
        values = {v for _, v in enums[f.enum].values} if f.enum else set()
        mask = 0
        for _, v in enums[f.flags].values if f.flags else ():
            mask |= v
        if (f.enum and d not in values) or (f.flags and int(d) & ~mask):
            raise SpecError(f"{msg.name}.{f.name}: default {d} is not a value of its enum")


def _check_measurement(msg: MessageSpec, enums: dict[str, EnumSpec]) -> None:
    """A measurement message: `meas_kind` names a member of enum meas_kind; its fields are t_us (u64), one or
    two anchor ids (u8), then the measured value (f32) - the shape the generated uwb_meas_decode() reads."""
    if msg.meas_kind not in dict(enums["meas_kind"].values):
        raise SpecError(f"{msg.name}: meas_kind {msg.meas_kind!r} is not a member of enum meas_kind")
    wires = [f.wire for f in msg.fields]
    if (msg.direction != "to_device" or len(wires) not in (2, 3, 4) or msg.fields[0].name != "t_us"
            or wires[0] != "u64" or wires[-1] != "f32" or any(w != "u8" for w in wires[1:-1])):
        raise SpecError(f"{msg.name}: a measurement message is to_device with fields t_us (u64), 0-2 anchor ids "
                        "(u8), value (f32)")


def load_spec(path: Path = SPEC_PATH) -> ProtocolSpec:
    """Parse and check the definition: unique ids and names, known types, frames fit max_body."""
    with open(path, "rb") as fh:
        raw = tomllib.load(fh)
    proto = raw["protocol"]
    enums = []
    for name, table in raw.get("enums", {}).items():
        values = tuple((k, int(v)) for k, v in table.items() if k != "doc")
        enums.append(EnumSpec(name=name, doc=str(table.get("doc", "")), values=values))
    enums_by_name = {e.name: e for e in enums}
    messages = []
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    for m in raw["message"]:
        fields = [_field(m["name"], entry, enums_by_name) for entry in m["fields"]]
        spec = MessageSpec(m["name"], int(m["id"]), m["dir"], m.get("doc", ""), tuple(fields), m.get("meas_kind"))
        if spec.meas_kind is not None:
            _check_measurement(spec, enums_by_name)
        if spec.msg_id in seen_ids or spec.name in seen_names:
            raise SpecError(f"duplicate message id or name: {spec.name} {spec.msg_id:#x}")
        if spec.direction not in ("to_device", "to_host"):
            raise SpecError(f"{spec.name}: dir must be to_device or to_host")
        body = HEADER_SIZE + spec.payload_size + CRC_SIZE
        if body > int(proto["max_body"]):
            raise SpecError(f"{spec.name}: body of {body} bytes exceeds max_body {proto['max_body']}")
        if spec.name == CONFIG_MESSAGE:
            _check_config(spec, enums_by_name)
        seen_ids.add(spec.msg_id)
        seen_names.add(spec.name)
        messages.append(spec)
    return ProtocolSpec(
        version=int(proto["version"]),
        max_body=int(proto["max_body"]),
        crc=str(proto["crc"]),
        max_anchors=int(proto["max_anchors"]),
        enums=tuple(enums),
        messages=tuple(messages),
    )
