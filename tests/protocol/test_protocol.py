"""The wire protocol on the host side: generated code is current, golden vectors, framing, resync."""

from __future__ import annotations

import os
import random
import struct

import pytest

from protocol import FrameDecoder, crc_info, encode_frame, generate, golden
from protocol import messages as m
from protocol.cobs import CobsError, cobs_decode, cobs_encode
from protocol.framing import Frame, ProtocolError, crc32c, decode_body, encode_body
from protocol.spec import load_spec


def test_generated_files_are_current() -> None:
    stale = [p for p, text in generate.outputs(load_spec()).items() if not p.exists() or p.read_text() != text]
    assert not stale, f"run `python -m protocol.generate`: stale {stale}"


def test_golden_file_is_current() -> None:
    assert golden.VECTORS_PATH.read_text() == golden.render()


def decode_golden_frame(frame: bytes) -> Frame:
    """A golden vector's frame (COBS, then the 0x00 delimiter) decoded."""
    if not frame.endswith(b"\x00"):
        raise ValueError("golden frame lacks its delimiter")
    return decode_body(cobs_decode(frame[:-1]))


def test_golden_vectors_decode_and_reencode_byte_identically() -> None:
    vectors = golden.parse(golden.VECTORS_PATH.read_text())
    assert len(vectors) >= 15
    names = set()
    for v in vectors:
        frame = decode_golden_frame(v["frame"])
        assert frame.seq == v["seq"]
        assert frame.msg.NAME == v["msg_name"]
        assert golden.format_fields(frame.msg) == v["fields"], v["name"]
        assert encode_frame(frame.msg, frame.seq) == v["frame"], v["name"]
        names.add(frame.msg.NAME)
    assert names == {cls.NAME for cls in m.MESSAGE_TYPES}, "every message type has a golden vector"


def test_crc_is_crc32c_and_reports_implementation() -> None:
    assert crc32c(b"123456789") == 0xE3069283
    info = crc_info()
    assert info["crc"] == "crc-32c"
    assert isinstance(info["crcmod_c_extension"], bool)


@pytest.mark.parametrize("n", [0, 1, 2, 253, 254, 255, 300, 600])
def test_cobs_roundtrip(n: int) -> None:
    rng = random.Random(n)
    for data in (bytes(n), bytes(rng.randrange(1, 256) for _ in range(n)), os.urandom(n)):
        enc = cobs_encode(data)
        assert b"\x00" not in enc
        assert cobs_decode(enc) == data


def test_cobs_rejects_invalid() -> None:
    with pytest.raises(CobsError):
        cobs_decode(b"\x05\x01\x02")
    with pytest.raises(CobsError):
        cobs_decode(b"\x03\x00\x01")


def test_decoder_resynchronises_after_garbage_and_counts_errors() -> None:
    good = [encode_frame(m.Twr(t_us=i, anchor_id=i % 8, range=1.0 + i), i) for i in range(5)]
    dec = FrameDecoder()
    stream = b"\xff" * 700 + b"\x00" + good[0] + b"\x01\x02\x03\x00" + good[1] + good[2][:-1] + b"\x00" + good[3]
    frames = dec.feed(stream)
    assert [f.seq for f in frames] == [0, 1, 2, 3]
    assert dec.errors.framing_errors >= 1
    # corrupt one byte inside a frame: CRC or framing rejects it, the next frame survives
    bad = bytearray(good[4])
    bad[5] ^= 0x40
    frames = dec.feed(bytes(bad) + good[4])
    assert [f.seq for f in frames] == [4]


def test_decoder_handles_byte_by_byte_delivery() -> None:
    msg = m.Result(**{name: (1.5 if wire == "f32" else 1) for name, wire in m.Result.FIELDS})
    frame = encode_frame(msg, 77)
    dec = FrameDecoder()
    out = []
    for b in frame:
        out += dec.feed(bytes([b]))
    assert len(out) == 1 and out[0].msg == msg and out[0].seq == 77


def test_decode_body_errors_are_classified() -> None:
    body = bytearray(encode_body(m.Twr(t_us=1, anchor_id=2, range=3.0), 9))
    with pytest.raises(ProtocolError) as e:
        decode_body(bytes(body[:5]))
    assert e.value.kind == "framing_errors"
    body[4] ^= 1
    with pytest.raises(ProtocolError) as e:
        decode_body(bytes(body))
    assert e.value.kind == "crc_errors"
    unknown = struct.pack("<BH", 0x7E, 1)
    with pytest.raises(ProtocolError) as e:
        decode_body(unknown + struct.pack("<I", crc32c(unknown)))
    assert e.value.kind == "unknown_types"
    short = struct.pack("<BH", m.Twr.MSG_ID, 1) + b"\x01\x02"
    with pytest.raises(ProtocolError) as e:
        decode_body(short + struct.pack("<I", crc32c(short)))
    assert e.value.kind == "bad_lengths"


def test_single_bit_flips_never_decode() -> None:
    frame = encode_frame(m.Tdoa(t_us=123, anchor_a=1, anchor_b=2, diff=0.5), 3)
    for bit in range((len(frame) - 1) * 8):
        bad = bytearray(frame)
        bad[bit // 8] ^= 1 << (bit % 8)
        dec = FrameDecoder()
        assert dec.feed(bytes(bad)) == [], bit
        # whatever happened, it was counted (a flip to 0x00 splits the frame in two bad ones)
        assert dec.errors.total() >= 1


def test_encode_refuses_out_of_range_values() -> None:
    with pytest.raises(ValueError, match="TWR"):
        encode_frame(m.Twr(t_us=-1, anchor_id=0, range=1.0), 0)
    with pytest.raises(ValueError):
        encode_frame(m.Anchor(anchor_id=300, x=0.0, y=0.0, z=0.0), 0)
