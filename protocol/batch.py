"""Vectorised framing for whole flights: encode thousands of frames (and decode RESULTs) with numpy.

A replay at hundreds of times real time cannot afford a Python loop per frame, so the streamer encodes a
flight once into one byte string with numpy (struct layout from the generated message classes, CRC-32C
and COBS done column-wise), and `ReplyDecoder` splits the device's output with the RESULT frames decoded
in bulk. The scalar codec in protocol.framing stays the reference: tests check that both produce
identical bytes and frames.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from protocol import messages as m
from protocol._generated import CRC_SIZE, HEADER_SIZE, MAX_BODY
from protocol.framing import DecoderErrors, Frame, FrameDecoder, crc32c
from protocol.spec import SCALARS

_POLY = 0x82F63B78

#: Below this many rows the per-row path (crcmod's C CRC, block-wise COBS) is faster: the column-wise
#: numpy path costs ~100 numpy calls per batch whatever its size, ~1 ms, which a reply reader that sees
#: a few RESULTs per read (lockstep, windowed) would pay on every read.
SMALL_BATCH = 128


def _crc_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ _POLY if c & 1 else c >> 1
        table[i] = c
    return table


_TABLE = _crc_table()


@functools.lru_cache(maxsize=None)
def body_dtype(cls: Any) -> np.dtype:
    """Packed structured dtype of a whole body: type, seq, fields..., crc."""
    fields: list[tuple[str, str]] = [("_type", "u1"), ("_seq", "<u2")]
    for name, wire in cls.FIELDS:
        fields.append((name, f"S{wire[5:]}" if wire.startswith("bytes") else SCALARS[wire][3]))
    fields.append(("_crc", "<u4"))
    dt = np.dtype(fields)
    assert dt.itemsize == HEADER_SIZE + cls.SIZE + CRC_SIZE <= MAX_BODY
    return dt


def crc32c_rows(rows: np.ndarray) -> np.ndarray:
    """CRC-32C of every row of a (n, L) uint8 array: column by column, or per row for small n."""
    n, length = rows.shape
    if n < SMALL_BATCH:
        flat = rows.tobytes()
        return np.fromiter((crc32c(flat[i:i + length]) for i in range(0, n * length, length)),
                           dtype=np.uint32, count=n)
    crc = np.full(rows.shape[0], 0xFFFFFFFF, dtype=np.uint32)
    for j in range(rows.shape[1]):
        crc = _TABLE[(crc ^ rows[:, j]) & 0xFF] ^ (crc >> np.uint32(8))
    return crc ^ np.uint32(0xFFFFFFFF)


def cobs_encode_rows(body: np.ndarray) -> np.ndarray:
    """COBS-encode rows shorter than 254 bytes: (n, L) -> (n, L + 1), no delimiter. Row r's bytes plus a virtual
    0x00 at column L, flattened: the zeros in order; each zero of the body becomes the distance to the next zero
    (always in the same row: the virtual one ends it) and the code byte in front the column of the row's first
    zero plus one. One pass over the zeros, whatever the rows hold."""
    n, length = body.shape
    if length >= 254:
        raise ValueError("row COBS encoder handles bodies below 254 bytes only")
    width = length + 1
    out = np.zeros((n, width), dtype=np.uint8)
    out[:, 1:] = body
    flat = out.reshape(-1)
    # the encoded layout shifted by one: the body's column c sits at c + 1, the virtual zero at the next row's 0
    zeros = np.flatnonzero(np.concatenate([flat[1:], np.zeros(1, np.uint8)]) == 0)
    inner = zeros % width != length                  # zeros of a body (not the virtual ends of the rows)
    at = zeros[:-1][inner[:-1]]
    flat[at + 1] = (zeros[1:][inner[:-1]] - at).astype(np.uint8)
    first = zeros[np.concatenate(([0], np.flatnonzero(~inner[:-1]) + 1))]
    flat[np.arange(n) * width] = (first % width + 1).astype(np.uint8)
    return out


def cobs_decode_rows(enc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decode rows encoded by a single COBS block each: (n, L + 1) -> ((n, L) body, (n,) valid)."""
    n, width = enc.shape
    length = width - 1
    if n < SMALL_BATCH and length < 254:
        return _cobs_decode_few(enc)
    body = enc[:, 1:].copy()
    valid = np.ones(n, dtype=bool)
    pos = enc[:, 0].astype(np.int64)          # absolute index of the next code byte
    rows = np.arange(n)
    valid &= enc[:, 0] != 0
    active = pos < width
    for _ in range(width):
        if not active.any():
            break
        r = rows[active]
        p = pos[active]
        body[r, p - 1] = 0                    # a code byte inside the row stands for a zero
        step = enc[r, p].astype(np.int64)
        bad = step == 0
        valid[r[bad]] = False
        pos[r] = p + np.where(bad, width, step)
        active = pos < width
    valid &= pos == width                     # the chain must land exactly on the end
    valid &= np.all(enc != 0, axis=1)
    if length >= 254:
        valid[:] = False
    return body, valid


def _cobs_decode_few(enc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-row COBS decoding, same result as the column-wise path. A row of width L + 1 < 255 holds no
    0xFF block, so decoding is: follow the code-byte chain from byte 0, each code byte standing for a
    zero of the body, and the chain must end exactly at the row's end."""
    n, width = enc.shape
    length = width - 1
    valid = np.zeros(n, dtype=bool)
    flat = enc.tobytes()
    parts: list[bytes | bytearray] = []
    for k in range(n):
        row = flat[k * width:(k + 1) * width]
        if 0 in row:
            parts.append(row[1:])
            continue
        body = bytearray(row[1:])
        p = row[0]
        while p < width:
            body[p - 1] = 0
            p += row[p]
        valid[k] = p == width
        parts.append(body)
    return np.frombuffer(b"".join(parts), dtype=np.uint8).reshape(n, length).copy(), valid


def encode_rows(cls: Any, columns: dict[str, np.ndarray], seqs: np.ndarray) -> np.ndarray:
    """Frames for n messages of one type: (n, L + 2) uint8 rows, each ending with the 0x00 delimiter."""
    dt = body_dtype(cls)
    n = len(seqs)
    arr = np.zeros(n, dtype=dt)
    arr["_type"] = cls.MSG_ID
    arr["_seq"] = (np.asarray(seqs) & 0xFFFF).astype(np.uint16)
    for name, _ in cls.FIELDS:
        arr[name] = columns[name]
    raw = arr.view(np.uint8).reshape(n, dt.itemsize)
    crc = crc32c_rows(raw[:, :-CRC_SIZE])
    arr["_crc"] = crc
    enc = cobs_encode_rows(raw)
    return np.concatenate([enc, np.zeros((n, 1), dtype=np.uint8)], axis=1)


def decode_rows(cls: Any, enc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decode (n, L + 1) COBS rows (no delimiter) of one type: (structured array, valid mask)."""
    dt = body_dtype(cls)
    body, valid = cobs_decode_rows(enc)
    if body.shape[1] != dt.itemsize:
        raise ValueError(f"{cls.NAME}: rows of {body.shape[1]} bytes, expected {dt.itemsize}")
    arr = np.ascontiguousarray(body).view(dt).reshape(-1)
    valid &= crc32c_rows(body[:, :-CRC_SIZE]) == arr["_crc"]
    valid &= arr["_type"] == cls.MSG_ID
    return arr, valid


RESULT_DTYPE = body_dtype(m.Result)
_RESULT_ENC_LEN = RESULT_DTYPE.itemsize + 1
#: a reply stream without a delimiter for this long is garbage: the scalar decoder counts it
_MAX_UNDELIMITED = 4096


def result_message(row: np.void) -> Frame:
    """One bulk-decoded RESULT row as the scalar decoder's Frame (same values: both read the same bytes)."""
    return Frame(int(row["_seq"]), m.Result(*(row[name].item() for name, _ in m.Result.FIELDS)))


class ReplyDecoder:
    """Splits device output into frames; RESULT frames (most of the traffic) are decoded in bulk with
    numpy, every other frame (and every RESULT the bulk path finds invalid) by the scalar FrameDecoder,
    which counts the errors."""

    def __init__(self) -> None:
        self._buf = b""
        self.decoder = FrameDecoder()

    @property
    def errors(self) -> DecoderErrors:
        return self.decoder.errors

    @property
    def frames_ok(self) -> int:
        return self.decoder.frames_ok

    def feed(self, data: bytes) -> tuple[np.ndarray, list[Frame]]:
        """(RESULT rows as RESULT_DTYPE, the other frames in order)."""
        buf = self._buf + data
        cut = buf.rfind(b"\x00")
        if cut < 0:
            self._buf = buf
            if len(buf) > _MAX_UNDELIMITED:  # no delimiter for this long: garbage, let the decoder count it
                self.decoder.feed(buf)
                self._buf = b""
            return np.zeros(0, RESULT_DTYPE), []
        self._buf = buf[cut + 1:]
        chunks = buf[:cut].split(b"\x00")
        # In a COBS frame the type byte (non-zero) sits unchanged right after the first code byte.
        res = [c for c in chunks if len(c) == _RESULT_ENC_LEN and c[1] == m.Result.MSG_ID]
        others = [c for c in chunks if c and not (len(c) == _RESULT_ENC_LEN and c[1] == m.Result.MSG_ID)]
        results = np.zeros(0, RESULT_DTYPE)
        if res:
            rows = np.frombuffer(b"".join(res), dtype=np.uint8).reshape(len(res), _RESULT_ENC_LEN)
            arr, valid = decode_rows(m.Result, rows)
            if not valid.all():
                # corrupted on the way: let the scalar decoder classify and count each one
                others += [res[i] for i in np.nonzero(~valid)[0]]
            results = arr[valid]
            self.decoder.frames_ok += len(results)
        frames = self.decoder.feed(b"".join(c + b"\x00" for c in others)) if others else []
        return results, frames
