"""`Device`: the lifecycle of a device under test (start, stop, alive) on top of a `Link`, and its protocol
session (`channel`, a DeviceChannel: harness/device/channel.py) with the HELLO handshake every device answers.

The link only moves bytes; the device knows whether the thing on the other end is still running. The
channel asks it (through `died`) whenever a read finds no input or the link closes, so a crashed host build
surfaces as DeviceDied (exit code + log tail) rather than as a silent timeout.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Any, TypeVar

from harness.device.channel import DeviceChannel
from harness.device.identity import DeviceIdentity
from harness.errors import DeviceDied, DeviceError, DeviceTimeout, ModelMismatch, ProtocolMismatch
from harness.link.base import Link
from protocol import PROTOCOL_VERSION
from protocol.messages import HelloReply

_T = TypeVar("_T")


class Device(ABC):
    """A device under test. Subclasses own the link and the process/board behind it."""

    hello_resend_s: float = 1.0   # HELLO is repeated this often while waiting (a board may be booting)

    def __init__(self) -> None:
        self._channel: DeviceChannel | None = None
        self._channel_link: Link | None = None

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

    # -------------------------------------------------------------- for the implementations
    def _running(self, part: _T | None) -> _T:
        """`part` (the link, the process) of a started device; DeviceError when it is not started."""
        if part is None:
            raise DeviceError(f"{self.name} is not started")
        return part

    def _not_running(self, part: object) -> None:
        """DeviceError when `part` says the device is already started (start() twice)."""
        if part is not None:
            raise DeviceError(f"{self.name} is already started")

    def died(self, grace_s: float = 0.0) -> DeviceDied | None:
        """DeviceDied if the device is known to have exited (waiting up to grace_s), else None."""
        return None

    # ----------------------------------------------------------------------------- protocol
    @property
    def channel(self) -> DeviceChannel:
        """The protocol session over the current link (a new one after every start)."""
        link = self.link
        if self._channel is None or self._channel_link is not link:
            self._channel = self._new_channel(link)
            self._channel_link = link
        return self._channel

    #: on a closed link, how long the channel waits for the device's exit to become visible
    death_grace_s: float = 0.5

    def _new_channel(self, link: Link) -> DeviceChannel:
        return DeviceChannel(link, self.died, death_grace_s=self.death_grace_s)

    @property
    def identity(self) -> DeviceIdentity:
        """Who the device said it is in the current session's HELLO (DeviceError before one)."""
        identity = self._channel.identity if self._channel is not None else None
        if identity is None:
            raise DeviceError(f"{self.name}: no HELLO answered in this session")
        return identity

    @property
    def last_hello(self) -> HelloReply | None:
        return self._channel.identity.reply if self._channel is not None and self._channel.identity else None

    def hello(self, timeout: float = 5.0) -> HelloReply:
        """Send HELLO with a random nonce; wait for the HELLO_REPLY carrying it (repeated every
        `hello_resend_s`). The identity stays available as `identity`."""
        try:
            return self.channel.hello(timeout, self.hello_resend_s).reply
        except DeviceTimeout as exc:
            raise DeviceTimeout(f"{exc} [{self.name}]", request=exc.request, waited_s=exc.waited_s) from None

    def check(self, expected_model_hash: int | str | None = None, expected_proto: int = PROTOCOL_VERSION,
              expected_layouts: tuple[int, int] | None = None) -> HelloReply:
        """Raise ProtocolMismatch / ModelMismatch unless the device is the expected firmware.
        Uses the session's HELLO (sends one first if there was none)."""
        reply = self.last_hello or self.hello()
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
        if self._channel is not None and self._channel.identity is not None:
            out.update(self.identity.describe())
        return out

    def connection(self) -> dict[str, Any]:
        """How the device is reached, for run summaries and JUnit: port (device path, URL or the host build's
        pty), baud (a serial link's), usb_serial (the USB serial number of a local serial port, if any)."""
        try:
            info = self.link.info()
        except Exception:  # noqa: BLE001 - not started: nothing to say
            return {"port": None, "baud": None, "usb_serial": None}
        port = info.get("url") or info.get("slave") or info.get("name")
        usb = None
        if info.get("kind") == "serial" and port:
            from harness.link.ports import serial_number_of
            usb = serial_number_of(str(port))
        return {"port": port, "baud": info.get("baud"), "usb_serial": usb}

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
