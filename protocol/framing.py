"""Frames on a byte stream: COBS( type:u8 | seq:u16 | payload | crc32c:u32 ) 0x00.

The CRC is computed with crcmod ('crc-32c'); `crc_info()` says whether crcmod's C extension is in use
(it silently falls back to pure Python when it could not be compiled, ~15x slower).
"""

from __future__ import annotations

import math
import struct
import sys
from dataclasses import dataclass, field, fields as dc_fields
from typing import Any, Callable

import crcmod.predefined

from protocol._generated import CRC_NAME, CRC_SIZE, HEADER_SIZE, MAX_BODY, MESSAGES_BY_ID
from protocol.cobs import CobsError, cobs_decode, cobs_encode

_HEADER = struct.Struct("<BH")
_CRC = struct.Struct("<I")
MAX_ENCODED = MAX_BODY + 1

crc32c: Callable[[bytes], int] = crcmod.predefined.mkCrcFun(CRC_NAME)


def crc_info() -> dict[str, object]:
    """Which CRC implementation is in use (report it: a missing C extension costs ~15x)."""
    mod = sys.modules.get("crcmod.crcmod") or sys.modules.get("crcmod")
    return {"crc": CRC_NAME, "crcmod_c_extension": bool(getattr(mod, "_usingExtension", False))}


class ProtocolError(ValueError):
    """A frame could not be decoded; `kind` is one of the FrameDecoder error counters."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Frame:
    seq: int
    msg: Any


def _payload(msg: Any) -> bytes:
    values = [getattr(msg, name) for name, _ in msg.FIELDS]
    try:
        return struct.pack(msg.FORMAT, *values)
    except struct.error as exc:
        raise ValueError(f"{msg.NAME}: cannot encode {values}: {exc}") from None


def encode_body(msg: Any, seq: int) -> bytes:
    """type | seq | payload | crc (before COBS)."""
    body = _HEADER.pack(msg.MSG_ID, seq & 0xFFFF) + _payload(msg)
    return body + _CRC.pack(crc32c(body))


def encode_frame(msg: Any, seq: int) -> bytes:
    """A complete frame for the wire, including the 0x00 delimiter."""
    return cobs_encode(encode_body(msg, seq)) + b"\x00"


def decode_body(body: bytes) -> Frame:
    """Decode a COBS-decoded body; raises ProtocolError(kind) with kind in FrameDecoder counters."""
    if len(body) < HEADER_SIZE + CRC_SIZE:
        raise ProtocolError("framing_errors", f"frame of {len(body)} bytes is shorter than header + crc")
    if crc32c(body[:-CRC_SIZE]) != _CRC.unpack_from(body, len(body) - CRC_SIZE)[0]:
        raise ProtocolError("crc_errors", "crc mismatch")
    msg_id, seq = _HEADER.unpack_from(body, 0)
    cls = MESSAGES_BY_ID.get(msg_id)
    if cls is None:
        raise ProtocolError("unknown_types", f"unknown message type {msg_id:#04x}")
    payload = body[HEADER_SIZE:-CRC_SIZE]
    if len(payload) != cls.SIZE:
        raise ProtocolError("bad_lengths", f"{cls.NAME}: payload of {len(payload)} bytes, expected {cls.SIZE}")
    return Frame(seq, cls(*struct.unpack(cls.FORMAT, payload)))


def is_finite(msg: Any) -> bool:
    return all(math.isfinite(getattr(msg, f.name)) for f in dc_fields(msg) if isinstance(getattr(msg, f.name), float))


@dataclass
class DecoderErrors:
    framing_errors: int = 0   # COBS errors, oversize, undersize
    crc_errors: int = 0
    unknown_types: int = 0
    bad_lengths: int = 0
    discarded_bytes: int = 0  # bytes thrown away with bad frames

    def total(self) -> int:
        return self.framing_errors + self.crc_errors + self.unknown_types + self.bad_lengths


@dataclass
class FrameDecoder:
    """Turns an arbitrary byte stream into frames; resynchronises on the next 0x00 after garbage."""

    errors: DecoderErrors = field(default_factory=DecoderErrors)
    frames_ok: int = 0
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[Frame]:
        out: list[Frame] = []
        self._buf += data
        if b"\x00" not in data:
            if len(self._buf) > MAX_ENCODED:  # no delimiter in sight: drop, count once per overflow
                self.errors.framing_errors += 1
                self.errors.discarded_bytes += len(self._buf)
                self._buf.clear()
            return out
        *chunks, rest = bytes(self._buf).split(b"\x00")
        self._buf = bytearray(rest)
        for enc in chunks:
            if not enc:
                continue  # back-to-back delimiters are allowed (resync padding)
            if len(enc) > MAX_ENCODED:
                self.errors.framing_errors += 1
                self.errors.discarded_bytes += len(enc)
                continue
            try:
                frame = decode_body(cobs_decode(enc))
            except CobsError:
                self.errors.framing_errors += 1
                self.errors.discarded_bytes += len(enc)
                continue
            except ProtocolError as exc:
                setattr(self.errors, exc.kind, getattr(self.errors, exc.kind) + 1)
                self.errors.discarded_bytes += len(enc)
                continue
            self.frames_ok += 1
            out.append(frame)
        return out
