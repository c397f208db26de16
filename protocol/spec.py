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


@dataclass(frozen=True)
class FieldSpec:
    name: str
    wire: str          # u8 u16 u32 u64 f32 bytesN
    doc: str = ""

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


def load_spec(path: Path = SPEC_PATH) -> ProtocolSpec:
    """Parse and check the definition: unique ids and names, known types, frames fit max_body."""
    with open(path, "rb") as fh:
        raw = tomllib.load(fh)
    proto = raw["protocol"]
    enums = []
    for name, table in raw.get("enums", {}).items():
        values = tuple((k, int(v)) for k, v in table.items() if k != "doc")
        enums.append(EnumSpec(name=name, doc=str(table.get("doc", "")), values=values))
    messages = []
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    for m in raw["message"]:
        fields = []
        for entry in m["fields"]:
            fname, wire = entry[0], entry[1]
            doc = entry[2] if len(entry) > 2 else ""
            if wire not in SCALARS and not (wire.startswith("bytes") and wire[5:].isdigit()):
                raise SpecError(f"{m['name']}.{fname}: unknown wire type {wire!r}")
            fields.append(FieldSpec(fname, wire, doc))
        spec = MessageSpec(m["name"], int(m["id"]), m["dir"], m.get("doc", ""), tuple(fields))
        if spec.msg_id in seen_ids or spec.name in seen_names:
            raise SpecError(f"duplicate message id or name: {spec.name} {spec.msg_id:#x}")
        if spec.direction not in ("to_device", "to_host"):
            raise SpecError(f"{spec.name}: dir must be to_device or to_host")
        body = HEADER_SIZE + spec.payload_size + CRC_SIZE
        if body > int(proto["max_body"]):
            raise SpecError(f"{spec.name}: body of {body} bytes exceeds max_body {proto['max_body']}")
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
