"""`Device`: the lifecycle of a device under test (start, stop, alive) on top of a `Link`, plus the
HELLO handshake every device answers. `FrameChannel`: frames over a link with a tx seq counter.

The link only moves bytes; the device knows whether the thing on the other end is still running.
FrameChannel asks it (through `died`) whenever a read times out or the link closes, so a crashed
emulator surfaces as DeviceDied (exit code + log tail) rather than as a silent timeout.
"""

from __future__ import annotations

import secrets
import time
from abc import ABC, abstractmethod
from collections import deque
from types import TracebackType
from typing import Any, Callable

from harness.errors import DeviceDied, DeviceTimeout, LinkClosed, ModelMismatch, ProtocolMismatch
from harness.link.base import DEFAULT_READ_SIZE, Link
from protocol import PROTOCOL_VERSION
from protocol.framing import Frame, FrameDecoder, encode_frame
from protocol.messages import Hello, HelloReply

DeathCheck = Callable[[float], "DeviceDied | None"]


def _never_died(grace_s: float) -> DeviceDied | None:  # noqa: ARG001 - a board we cannot observe
    return None


class FrameChannel:
    """Protocol frames over a link: encodes with a running seq, decodes with a FrameDecoder.

    `died(grace_s)` returns a DeviceDied if the device has exited (waiting up to `grace_s` for the
    exit to become visible), else None.
    """

    def __init__(self, link: Link, died: DeathCheck = _never_died, seq0: int = 0,
                 poll_s: float = 0.1, death_grace_s: float = 0.5) -> None:
        self.link = link
        self.decoder = FrameDecoder()
        self._died = died
        self._seq = seq0 & 0xFFFF
        self._pending: deque[Frame] = deque()
        self._poll_s = poll_s
        self._death_grace_s = death_grace_s
        self._resynced = False
        self.skipped = 0    # frames expect() read past while waiting for another one

    @property
    def next_seq(self) -> int:
        """The seq the next send() will use (hand it on when another writer takes over the link)."""
        return self._seq

    @property
    def errors(self) -> Any:
        return self.decoder.errors

    def send(self, msg: Any) -> int:
        """Send one message; returns its seq."""
        seq = self._seq
        data = encode_frame(msg, seq)
        if not self._resynced:
            # A leading delimiter ends whatever half frame the device may hold (line noise, a
            # previous session); empty frames are ignored by both sides.
            data = b"\x00" + data
        try:
            self.link.write(data)
        except LinkClosed as exc:
            raise self._death_or(exc) from exc
        self._resynced = True
        self._seq = (seq + 1) & 0xFFFF
        return seq

    def recv(self, timeout: float) -> Frame | None:
        """The next frame, or None after `timeout` s. DeviceDied if the device exited meanwhile."""
        deadline = time.monotonic() + max(0.0, timeout)
        while not self._pending:
            left = deadline - time.monotonic()
            try:
                data = self.link.read(DEFAULT_READ_SIZE, max(0.0, min(left, self._poll_s)))
            except LinkClosed as exc:
                raise self._death_or(exc) from exc
            if data:
                self._pending.extend(self.decoder.feed(data))
                if not self._pending and deadline - time.monotonic() <= 0:
                    return None    # a peer that floods bytes without a frame must not hold us past the deadline
                continue
            dead = self._died(0.0)  # input is drained: a dead device has nothing more to say
            if dead is not None:
                raise dead
            if left <= 0:
                return None
        return self._pending.popleft()

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

    def _death_or(self, exc: LinkClosed) -> Exception:
        dead = self._died(self._death_grace_s)
        return dead if dead is not None else exc

    def diagnosis(self) -> str:
        errs = self.decoder.errors
        total = errs.total() if hasattr(errs, "total") else errs
        return f"link {self.link.name}, {self.decoder.frames_ok} frames decoded, {self.skipped} skipped, " \
               f"decoder errors {total}"


class Device(ABC):
    """A device under test. Subclasses own the link and the process/board behind it."""

    hello_resend_s: float = 1.0   # HELLO is repeated this often while waiting (a board may be booting)

    def __init__(self) -> None:
        self._channel: FrameChannel | None = None
        self._last_hello: HelloReply | None = None

    # -------------------------------------------------------------------------- to implement
    @property
    @abstractmethod
    def name(self) -> str: ...

    @property
    @abstractmethod
    def link(self) -> Link:
        """The byte transport; raises DeviceError when the device is not started."""

    @abstractmethod
    def start(self) -> None: ...

    @abstractmethod
    def stop(self) -> int | None:
        """Stop (idempotent); returns the process exit code where there is one."""

    @abstractmethod
    def alive(self) -> bool: ...

    def died(self, grace_s: float = 0.0) -> DeviceDied | None:
        """DeviceDied if the device is known to have exited (waiting up to grace_s), else None."""
        return None

    # ----------------------------------------------------------------------------- protocol
    @property
    def channel(self) -> FrameChannel:
        """Frame channel over the current link (a new one after every start)."""
        link = self.link
        if self._channel is None or self._channel.link is not link:
            self._channel = self._new_channel(link)
        return self._channel

    def _new_channel(self, link: Link) -> FrameChannel:
        return FrameChannel(link, self.died)

    @property
    def last_hello(self) -> HelloReply | None:
        return self._last_hello

    def hello(self, timeout: float = 5.0) -> HelloReply:
        """Send HELLO with a random nonce; wait for the HELLO_REPLY carrying it."""
        nonce = secrets.randbits(32)
        channel = self.channel
        start = time.monotonic()
        deadline = start + max(0.0, timeout)
        sent = 0
        while True:
            channel.send(Hello(nonce=nonce))
            sent += 1
            wait = min(self.hello_resend_s, max(0.0, deadline - time.monotonic()))
            try:
                frame = channel.expect(lambda f: isinstance(f.msg, HelloReply) and f.msg.nonce == nonce,
                                       wait, "HELLO")
            except DeviceTimeout:
                if time.monotonic() < deadline:
                    continue
                raise DeviceTimeout.for_request(
                    "HELLO", time.monotonic() - start,
                    f"{self.name}: nonce {nonce:#010x}, sent {sent}x; {channel.diagnosis()}") from None
            reply: HelloReply = frame.msg
            self._last_hello = reply
            return reply

    def check(self, expected_model_hash: int | str | None = None, expected_proto: int = PROTOCOL_VERSION,
              expected_layouts: tuple[int, int] | None = None) -> HelloReply:
        """Raise ProtocolMismatch / ModelMismatch unless the device is the expected firmware.
        Uses the last HELLO_REPLY (sends HELLO first if there was none)."""
        reply = self._last_hello or self.hello()
        if reply.proto_version != expected_proto:
            raise ProtocolMismatch.versions(expected_proto, reply.proto_version)
        want = _as_hash(expected_model_hash)
        layouts = (reply.layout_twr, reply.layout_tdoa)
        if (want is not None and want != reply.model_hash) or \
                (expected_layouts is not None and tuple(expected_layouts) != layouts):
            raise ModelMismatch.hashes(want, reply.model_hash, layouts, expected_layouts)
        return reply

    def describe(self) -> dict[str, Any]:
        """Who the device is and how it is connected (for reports)."""
        out: dict[str, Any] = {"name": self.name}
        try:
            out["link"] = self.link.info()
        except Exception:  # noqa: BLE001 - not started: no link to describe
            pass
        reply = self._last_hello
        if reply is not None:
            out.update(proto_version=reply.proto_version,
                       firmware=f"{reply.fw_major}.{reply.fw_minor}.{reply.fw_patch}",
                       build_id=_ascii(reply.build_id), target=_ascii(reply.target),
                       model_hash=f"{reply.model_hash:#018x}", cost_unit=reply.cost_unit,
                       layout_twr=reply.layout_twr, layout_tdoa=reply.layout_tdoa)
        return out

    # ------------------------------------------------------------------------ context manager
    def __enter__(self) -> Device:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}>"


def _as_hash(value: int | str | None) -> int | None:
    if value is None or isinstance(value, int):
        return value
    return int(value, 16)


def _ascii(raw: bytes) -> str:
    return raw.rstrip(b"\x00").decode("ascii", errors="replace")
