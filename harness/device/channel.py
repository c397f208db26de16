"""`DeviceChannel`: the one protocol session between the harness and a device, over a `Link`.

It owns everything a frame exchange needs, so that no caller keeps its own copy:
  * the tx sequence number (nobody else counts seqs: a whole flight reserves its block with `reserve`);
  * the reply decoder, with RESULT frames decoded in bulk (protocol.batch.ReplyDecoder): `read()` gives
    RESULT rows as a numpy array plus the other frames, `recv()` / `expect()` one frame at a time;
    whatever one reader pulled from the link and did not use stays pending for the next;
  * the mapping of link errors to device errors: a closed link, or a read that found the input drained,
    asks the device (`died`) whether it exited, so a crashed host build surfaces as DeviceDied (exit code
    and log tail) rather than as a silent timeout or a bare LinkClosed;
  * the identity from HELLO (`hello()` -> DeviceIdentity, kept as `identity`), and the requests every
    run makes: `configure(config, anchors, reset)`, `stats()`, `clock()`.
Pacing (what to send when) is the caller's: harness/stream/streamer.py, harness/closedloop/cosim.py.
"""

from __future__ import annotations

import secrets
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from harness.config import EstimatorConfig
from harness.device.identity import DeviceIdentity
from harness.errors import DeviceDied, DeviceError, DeviceTimeout, LinkClosed
from harness.link.base import DEFAULT_READ_SIZE
from protocol import messages as m
from protocol.batch import RESULT_DTYPE, ReplyDecoder, result_message
from protocol.framing import DecoderErrors, Frame, encode_frame

DeathCheck = Callable[[float], "DeviceDied | None"]


class LinkLike(Protocol):
    """What the channel needs of a transport (harness.link.base.Link has it)."""

    @property
    def name(self) -> str: ...
    def write(self, data: bytes) -> None: ...
    def read(self, max_bytes: int, timeout: float) -> bytes: ...


class AnchorsLike(Protocol):
    ids: Any           # (N,) anchor ids
    positions: Any     # (N, 3) metres


def never_died(grace_s: float) -> DeviceDied | None:  # noqa: ARG001 - a board we cannot observe
    return None


@dataclass
class Replies:
    """What one read brought: RESULT rows (RESULT_DTYPE, with `_seq`), the other frames, when it arrived."""

    results: np.ndarray
    frames: list[Frame]
    t_ns: int            # time.perf_counter_ns() when the bytes were read

    def __bool__(self) -> bool:
        return bool(len(self.results) or self.frames)


def config_message(config: EstimatorConfig, reset: bool) -> m.Config:
    """The CONFIG message of an estimator configuration (validated first)."""
    config.validate()
    return config.to_message(reset=int(reset))


def setup_messages(config: EstimatorConfig, anchors: AnchorsLike | None, reset: bool = True) -> list[Any]:
    """CONFIG, then one ANCHOR per anchor (None: no anchors, e.g. at radio level their positions come over
    the air in the packets' LPP): what goes ahead of every flight."""
    msgs: list[Any] = [config_message(config, reset)]
    if anchors is not None:
        msgs += [m.Anchor(anchor_id=int(aid), x=float(pos[0]), y=float(pos[1]), z=float(pos[2]))
                 for aid, pos in zip(anchors.ids, anchors.positions)]
    return msgs


class DeviceChannel:
    """The protocol session over `link`. `died(grace_s)` returns a DeviceDied if the device has exited
    (waiting up to grace_s for the exit to become visible), else None."""

    def __init__(self, link: LinkLike, died: DeathCheck = never_died, poll_s: float = 0.1,
                 death_grace_s: float = 0.5) -> None:
        self.link = link
        self._died = died
        self._seq = 0
        self._reader = ReplyDecoder()
        self._pending: deque[Frame | np.ndarray] = deque()
        self._pending_t_ns = 0
        self._poll_s = poll_s
        self._death_grace_s = death_grace_s
        self._resynced = False
        self.skipped = 0                          # frames expect() read past while waiting for another one
        self.identity: DeviceIdentity | None = None

    # ------------------------------------------------------------------------------- sequence
    @property
    def next_seq(self) -> int:
        """The seq the next frame will carry (read only: `reserve` and the senders advance it)."""
        return self._seq

    def reserve(self, count: int) -> int:
        """Reserve `count` consecutive seqs for frames encoded elsewhere (a whole flight at once);
        returns the first."""
        first = self._seq
        self._seq = (first + max(0, int(count))) & 0xFFFF
        return first

    def frame(self, msg: Any) -> tuple[bytes, int]:
        """Encode `msg` with the next seq, without sending it (several frames go out in one write)."""
        seq = self.reserve(1)
        return encode_frame(msg, seq), seq

    # ------------------------------------------------------------------------------- decoder
    @property
    def errors(self) -> DecoderErrors:
        """What the host could not decode so far (cumulative over the session)."""
        return self._reader.errors

    @property
    def frames_ok(self) -> int:
        return self._reader.frames_ok

    # --------------------------------------------------------------------------------- writing
    def write(self, data: bytes) -> None:
        """Write encoded frames; a closed link becomes DeviceDied when the device is gone."""
        if not self._resynced:
            # A leading delimiter ends whatever half frame the device may hold (line noise, a
            # previous session); empty frames are ignored by both sides.
            data = b"\x00" + data
        try:
            self.link.write(data)
        except LinkClosed as exc:
            raise self._death_or(exc, "while writing") from exc
        self._resynced = True

    def send(self, msg: Any) -> int:
        """Send one message; returns its seq."""
        data, seq = self.frame(msg)
        self.write(data)
        return seq

    #: bytes per write between reads. The device answers a 21-byte TWR with a ~115-byte RESULT; if the
    #: harness wrote a long burst without reading, the device's replies could fill the pty while it is
    #: still being written to, both sides would block in write() and the run would fail after the write
    #: timeout with a false "device stopped reading" (seen under load in realtime pacing).
    WRITE_SLICE = 2048

    def write_stream(self, data: bytes, on_replies: Callable[[Replies], None] | None = None) -> None:
        """Write a long stream in slices, reading (without waiting) between them; what was read goes to
        `on_replies` at once (its arrival time is the latency's end), or stays pending without one."""
        for off in range(0, len(data), self.WRITE_SLICE):
            self.write(data[off:off + self.WRITE_SLICE])
            if off + self.WRITE_SLICE < len(data):
                got = self._read_link(0.0)
                if got:
                    if on_replies is not None:
                        on_replies(got)
                    else:
                        self._keep(got)

    # --------------------------------------------------------------------------------- reading
    def read(self, timeout: float) -> Replies:
        """What is pending, else what one read of the link brings within `timeout` (maybe nothing)."""
        if self._pending:
            rows = [p for p in self._pending if isinstance(p, np.ndarray)]
            frames = [p for p in self._pending if isinstance(p, Frame)]
            self._pending.clear()
            return Replies(np.concatenate(rows) if rows else np.zeros(0, RESULT_DTYPE), frames, self._pending_t_ns)
        return self._read_link(timeout)

    def _read_link(self, timeout: float) -> Replies:
        try:
            data = self.link.read(DEFAULT_READ_SIZE, max(0.0, timeout))
        except LinkClosed as exc:
            raise self._death_or(exc, "while reading") from exc
        if not data:
            dead = self._died(0.0)  # input is drained: a dead device has nothing more to say
            if dead is not None:
                raise self._named(dead, "while reading")
            return Replies(np.zeros(0, RESULT_DTYPE), [], time.perf_counter_ns())
        results, frames = self._reader.feed(data)
        return Replies(results, frames, time.perf_counter_ns())

    def _keep(self, got: Replies) -> None:
        if not self._pending:
            self._pending_t_ns = got.t_ns
        if len(got.results):
            self._pending.append(got.results)
        self._pending.extend(got.frames)

    def recv(self, timeout: float) -> Frame | None:
        """The next frame, or None after `timeout` s. DeviceDied if the device exited meanwhile."""
        deadline = time.monotonic() + max(0.0, timeout)
        while not self._pending:
            left = deadline - time.monotonic()
            got = self._read_link(max(0.0, min(left, self._poll_s)))
            if got:
                self._keep(got)
            elif left <= 0:
                return None
            if not self._pending and deadline - time.monotonic() <= 0:
                return None    # a peer that floods bytes without a frame must not hold us past the deadline
        head = self._pending.popleft()
        if isinstance(head, Frame):
            return head
        if len(head) > 1:
            self._pending.appendleft(head[1:])
        return result_message(head[0])

    def expect(self, match: Callable[[Frame], bool], timeout: float, request: str) -> Frame:
        """The first frame for which `match` is true; other frames are skipped (and counted)."""
        start = time.monotonic()
        deadline = start + max(0.0, timeout)
        while True:
            frame = self.recv(max(0.0, deadline - time.monotonic()))
            if frame is not None and match(frame):
                return frame
            if frame is not None:
                self.skipped += 1
            # checked after every frame too: a peer sending other frames back to back must not hold us
            if time.monotonic() >= deadline:
                raise DeviceTimeout.for_request(request, time.monotonic() - start, self.diagnosis())

    # ------------------------------------------------------------------------------- requests
    def hello(self, timeout: float = 5.0, resend_s: float = 1.0) -> DeviceIdentity:
        """HELLO with a random nonce, repeated every `resend_s` (a board may be booting) until the
        HELLO_REPLY carrying it; the identity is kept as `identity`."""
        nonce = secrets.randbits(32)
        start = time.monotonic()
        deadline = start + max(0.0, timeout)
        sent = 0
        while True:
            self.send(m.Hello(nonce=nonce))
            sent += 1
            wait = min(resend_s, max(0.0, deadline - time.monotonic()))
            try:
                frame = self.expect(lambda f: isinstance(f.msg, m.HelloReply) and f.msg.nonce == nonce, wait, "HELLO")
            except DeviceTimeout:
                if time.monotonic() < deadline:
                    continue
                raise DeviceTimeout.for_request(
                    "HELLO", time.monotonic() - start,
                    f"nonce {nonce:#010x}, sent {sent}x; {self.diagnosis()}") from None
            self.identity = DeviceIdentity.from_reply(frame.msg)
            return self.identity

    def configure(self, config: EstimatorConfig, anchors: AnchorsLike | None, reset: bool = True,
                  timeout: float = 5.0) -> m.Stats:
        """CONFIG (with or without filter reset) and the anchors, in one write with a STATS_REQ behind them;
        returns that STATS (the counters once the set-up is done).
        CONFIG and ANCHOR are answered only when refused, and the device handles frames in order: once its
        STATS is back, every refusal has arrived. A refusal is a DeviceError (without the barrier, one that
        came after the first read let the run go on with the device's previous configuration and pass);
        every other frame read meanwhile stays pending for the caller."""
        msgs = setup_messages(config, anchors, reset)
        first = self.reserve(len(msgs))
        setup = b"".join(encode_frame(msg, first + i) for i, msg in enumerate(msgs))
        self.write(setup + self.frame(m.StatsReq())[0])
        seqs = {(first + i) & 0xFFFF for i in range(len(msgs))}
        start = time.monotonic()
        deadline = start + max(0.0, timeout)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeout.for_request("CONFIG", time.monotonic() - start,
                                                f"no STATS behind the setup; {self.diagnosis()}")
            got = self._read_link(min(left, self._poll_s))
            barrier = next((f for f in got.frames if isinstance(f.msg, m.Stats)), None)
            for f in got.frames:
                if isinstance(f.msg, m.Error) and f.msg.msg_seq in seqs:
                    raise DeviceError(f"device refused the setup: {f.msg}")
            rest = Replies(got.results, [f for f in got.frames if f is not barrier], got.t_ns)
            if rest:
                self._keep(rest)
            if barrier is not None:
                return barrier.msg

    def stats(self, timeout: float = 5.0) -> m.Stats:
        """The device counters (STATS_REQ -> STATS); also the liveness probe after a silence."""
        self.send(m.StatsReq())
        return self.expect(lambda f: isinstance(f.msg, m.Stats), timeout, "STATS").msg

    def clock(self, anchor_id: int, timeout: float = 5.0) -> m.Clock:
        """The TDoA engine's clock correction of one anchor (CLOCK_REQ -> CLOCK)."""
        self.send(m.ClockReq(anchor_id=anchor_id))
        return self.expect(lambda f: isinstance(f.msg, m.Clock) and f.msg.anchor_id == anchor_id, timeout,
                           "CLOCK").msg

    @contextmanager
    def through(self, link: LinkLike) -> Iterator[DeviceChannel]:
        """This session over another transport to the same device for a while (e.g. a FaultyLink
        wrapping it): seq, decoder and identity carry on."""
        saved, self.link = self.link, link
        try:
            yield self
        finally:
            self.link = saved

    # ------------------------------------------------------------------------------- errors
    def _named(self, dead: DeviceDied, what: str) -> DeviceDied:
        return DeviceDied(f"device died {what}: {dead.message}", exit_code=dead.exit_code, log_tail=dead.log_tail,
                          log_path=dead.log_path)

    def _death_or(self, exc: LinkClosed, what: str) -> Exception:
        dead = self._died(self._death_grace_s)
        return self._named(dead, what) if dead is not None else exc

    def diagnosis(self) -> str:
        return f"link {self.link.name}, {self._reader.frames_ok} frames decoded, {self.skipped} skipped, " \
               f"decoder errors {self._reader.errors.total()}"


def as_channel(device_or_channel: Any) -> DeviceChannel:
    """A DeviceChannel as given, or the session of a started device (its `channel`)."""
    if isinstance(device_or_channel, DeviceChannel):
        return device_or_channel
    return device_or_channel.channel  # type: ignore[no-any-return]
