"""`FaultyLink`: wraps a `Link` and injects transport faults, seeded and counted.

Faults (each at its own rate, drawn from one seeded generator, so a run is reproducible):
  bit_flip         per byte: one random bit of the byte is inverted;
  drop_byte        per byte: the byte is not sent;
  drop_frame       per frame: the whole frame (with its delimiter) is not sent;
  duplicate_frame  per frame: the frame is sent twice;
  truncate_frame   per frame: the frame is cut at a random point (its delimiter is kept);
  garbage          per frame: a burst of 1..garbage_max random bytes goes out before the frame;
  stall            per write/read: the call first sleeps `stall_s` (a busy or slow peer).

Faults are applied per frame (bytes up to and including a 0x00 delimiter). By default only data frames
are faulted (IMU, TWR, TDOA towards the device; RESULT, ERROR back): the setup and the STATS exchange
that the accounting relies on stay intact. Every frame the link lets through is also fed to a shadow
`FrameDecoder` per direction, so the link knows exactly what the peer received: which frames (by seq)
arrived intact and how many bad frames the peer's parser must count. Tests compare those with the
device's STATS and with the run's results.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.errors import UsageError
from harness.link.base import DEFAULT_READ_SIZE, Link
from protocol import messages as m
from protocol.cobs import CobsError, cobs_decode
from protocol.framing import Frame, FrameDecoder, ProtocolError, decode_body

DATA_TO_DEVICE = frozenset({m.Imu.MSG_ID, m.Twr.MSG_ID, m.Tdoa.MSG_ID})
DATA_TO_HOST = frozenset({m.Result.MSG_ID, m.Error.MSG_ID})


@dataclass(frozen=True)
class FaultRates:
    """Probabilities of each fault (0 = off). Per byte: bit_flip, drop_byte; per frame: the rest."""

    bit_flip: float = 0.0
    drop_byte: float = 0.0
    drop_frame: float = 0.0
    duplicate_frame: float = 0.0
    truncate_frame: float = 0.0
    garbage: float = 0.0
    garbage_max: int = 64
    stall: float = 0.0
    stall_s: float = 0.05

    def __post_init__(self) -> None:
        for name in ("bit_flip", "drop_byte", "drop_frame", "duplicate_frame", "truncate_frame", "garbage",
                     "stall"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise UsageError(f"fault rate {name} must be within [0, 1], got {value}")
        if self.garbage_max < 1:
            raise UsageError("garbage_max must be >= 1")
        if not 0.0 <= self.stall_s <= 10.0:
            raise UsageError("stall_s must be within [0, 10] s")

    @property
    def any(self) -> bool:
        return any(getattr(self, n) > 0 for n in ("bit_flip", "drop_byte", "drop_frame", "duplicate_frame",
                                                   "truncate_frame", "garbage", "stall"))


@dataclass
class DirectionLog:
    """What the link did in one direction, and what the peer therefore received."""

    counts: Counter[str] = field(default_factory=Counter)
    # keys: frame_key() unwrapped to a running count (see unwrap_seqs), so seqs never collide
    sent_seqs: list[int] = field(default_factory=list)       # key of every original data frame
    damaged_seqs: set[int] = field(default_factory=set)       # altered, dropped, or hit by garbage
    delivered: FrameDecoder = field(default_factory=FrameDecoder)   # shadow of the peer's parser
    intact_seqs: Counter[int] = field(default_factory=Counter)  # key -> copies delivered intact

    @property
    def lost_seqs(self) -> set[int]:
        """Data frames (by seq) of which no copy reached the peer intact."""
        return {s for s in self.sent_seqs if self.intact_seqs[s] == 0}

    def summary(self) -> dict[str, Any]:
        errs = self.delivered.errors
        return {**dict(self.counts), "data_frames": len(self.sent_seqs), "lost_frames": len(self.lost_seqs),
                "delivered_ok": self.delivered.frames_ok, "delivered_crc_errors": errs.crc_errors,
                "delivered_framing_errors": errs.framing_errors}


class SeqUnwrap:
    """16-bit seq -> running 64-bit count (frames come in order; a long run wraps the seq many times)."""

    def __init__(self) -> None:
        self.last: int | None = None

    def __call__(self, seq: int) -> int:
        if self.last is None:
            self.last = seq
            return seq
        d = (seq - self.last) & 0xFFFF
        self.last += d - 0x10000 if d >= 0x8000 else d
        return self.last


def unwrap_seqs(seqs: Any) -> np.ndarray:
    """Unwrap a sequence of 16-bit seqs given in stream order (e.g. RESULTS meas_seq)."""
    u = SeqUnwrap()
    return np.array([u(int(s)) for s in seqs], dtype=np.int64)


def frame_key(frame: Frame) -> int:
    """What a data frame stands for: the measurement seq (RESULT / ERROR refer to it), else its seq."""
    msg = frame.msg
    if isinstance(msg, m.Result):
        return int(msg.meas_seq)
    if isinstance(msg, m.Error):
        return int(msg.msg_seq)
    return int(frame.seq)


def _decode_enc(enc: bytes) -> Frame | None:
    try:
        return decode_body(cobs_decode(enc))
    except (CobsError, ProtocolError):
        return None


class _Injector:
    """Applies FaultRates to one direction's byte stream, frame by frame."""

    def __init__(self, rates: FaultRates, rng: np.random.Generator, fault_types: frozenset[int]) -> None:
        self.rates = rates
        self.rng = rng
        self.fault_types = fault_types
        self.log = DirectionLog()
        self._tail = b""
        self._unwrap_sent = SeqUnwrap()
        self._unwrap_delivered = SeqUnwrap()

    def process(self, data: bytes) -> bytes:
        """Faulted bytes for `data`; an incomplete trailing frame waits for its delimiter."""
        buf = self._tail + data
        cut = buf.rfind(b"\x00") + 1          # 0: no complete frame yet
        self._tail = buf[cut:]
        out = bytearray()
        if cut:
            for enc in buf[:cut - 1].split(b"\x00"):
                out += self._frame(enc)
        wire = bytes(out)
        for f in self.log.delivered.feed(wire):
            if f.msg.MSG_ID in self.fault_types:
                self.log.intact_seqs[self._unwrap_delivered(frame_key(f))] += 1
        return wire

    def _frame(self, enc: bytes) -> bytes:
        """One frame (without its delimiter) -> the bytes that go on the wire for it."""
        r, rng, c = self.rates, self.rng, self.log.counts
        # In a COBS frame the (non-zero) type byte sits right after the first code byte.
        if len(enc) < 2 or enc[1] not in self.fault_types:
            return enc + b"\x00"
        original = _decode_enc(enc)
        key = self._unwrap_sent(frame_key(original)) if original is not None else -1
        c["frames"] += 1
        self.log.sent_seqs.append(key)
        prefix = b""
        if r.garbage and rng.random() < r.garbage:
            n = int(rng.integers(1, r.garbage_max + 1))
            prefix = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            c["garbage_bursts"] += 1
            c["garbage_bytes"] += n
        if r.drop_frame and rng.random() < r.drop_frame:
            c["dropped_frames"] += 1
            self.log.damaged_seqs.add(key)
            return prefix    # garbage (if any) still goes out and merges with the next frame
        body = bytearray(enc)
        altered = False
        if r.truncate_frame and rng.random() < r.truncate_frame:
            del body[int(rng.integers(0, len(body))):]
            c["truncated_frames"] += 1
            altered = True
        if r.drop_byte and body:
            keep = rng.random(len(body)) >= r.drop_byte
            if not keep.all():
                c["dropped_bytes"] += int((~keep).sum())
                c["frames_with_dropped_bytes"] += 1
                body = bytearray(np.frombuffer(bytes(body), np.uint8)[keep].tobytes())
                altered = True
        if r.bit_flip and body:
            hits = np.nonzero(rng.random(len(body)) < r.bit_flip)[0]
            if len(hits):
                for i, bit in zip(hits.tolist(), rng.integers(0, 8, len(hits)).tolist()):
                    body[i] ^= 1 << bit
                c["flipped_bits"] += len(hits)
                c["frames_with_flipped_bits"] += 1
                altered = True
        if altered or prefix:
            self.log.damaged_seqs.add(key)
        wire = prefix + bytes(body) + b"\x00"
        if r.duplicate_frame and rng.random() < r.duplicate_frame:
            c["duplicated_frames"] += 1
            wire += bytes(body) + b"\x00"
        return wire


class FaultyLink(Link):
    """A `Link` that injects seeded faults into what is written (tx) and/or read (rx)."""

    #: Runs over this link expect device refusals (CRC, framing, ...): the verdict does not fail them.
    injects_faults = True

    def __init__(self, inner: Link, tx: FaultRates = FaultRates(), rx: FaultRates = FaultRates(),
                 seed: int = 0, tx_types: frozenset[int] = DATA_TO_DEVICE,
                 rx_types: frozenset[int] = DATA_TO_HOST) -> None:
        self.inner = inner
        self.enabled = True
        rng = np.random.default_rng(seed)
        self._tx = _Injector(tx, np.random.default_rng(rng.integers(2**63)), tx_types)
        self._rx = _Injector(rx, np.random.default_rng(rng.integers(2**63)), rx_types)
        self._stall_rng = np.random.default_rng(rng.integers(2**63))
        self._rx_ready = b""

    # ------------------------------------------------------------------------------ reports
    @property
    def tx_log(self) -> DirectionLog:
        return self._tx.log

    @property
    def rx_log(self) -> DirectionLog:
        return self._rx.log

    def report(self) -> dict[str, Any]:
        return {"tx": self._tx.log.summary(), "rx": self._rx.log.summary()}

    # --------------------------------------------------------------------------- Link API
    @property
    def name(self) -> str:
        return f"faulty({self.inner.name})"

    @property
    def closed(self) -> bool:
        return self.inner.closed

    def info(self) -> dict[str, Any]:
        return {**self.inner.info(), "name": self.name, "faults": self.report()}

    def _maybe_stall(self, rates: FaultRates, log: DirectionLog) -> None:
        if self.enabled and rates.stall and self._stall_rng.random() < rates.stall:
            log.counts["stalls"] += 1
            time.sleep(rates.stall_s)

    def write(self, data: bytes) -> None:
        if not self.enabled:
            self.inner.write(data)
            return
        self._maybe_stall(self._tx.rates, self._tx.log)
        wire = self._tx.process(data)
        if wire:
            self.inner.write(wire)

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.0) -> bytes:
        deadline = time.monotonic() + max(0.0, timeout)
        while not self._rx_ready:
            data = self.inner.read(max_bytes, max(0.0, deadline - time.monotonic()))
            if data:
                if self.enabled:
                    self._maybe_stall(self._rx.rates, self._rx.log)
                    self._rx_ready += self._rx.process(data)
                else:
                    self._rx_ready += data
            if time.monotonic() >= deadline:
                break
        out, self._rx_ready = self._rx_ready[:max_bytes], self._rx_ready[max_bytes:]
        return out

    def close(self) -> None:
        self.inner.close()

