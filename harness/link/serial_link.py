"""`SerialLink`: any pyserial port or URL (/dev/tty*, rfc2217://, socket://, loop://, spy://, ...).

The pyserial object is kept non-blocking (timeout 0): read() waits with select() on its fd where it
has one (device files, socket://, spy://) and polls `in_waiting` otherwise (loop://, rfc2217://),
so a read returns as soon as data is there and changing the wait never re-configures the port
(pyserial re-applies termios, or re-negotiates RFC 2217, on every timeout change).
Writes use pyserial's write timeout; a stuck peer raises LinkTimeout. Backends that refuse a write
timeout (pyserial's RFC 2217 driver: "write_timeout is currently not supported") are opened without
one and the timeout is emulated: the blocking write runs in a helper thread and the caller waits for it
with the deadline; past it the port is closed (which unblocks the thread) and LinkTimeout is raised.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit, urlunsplit

import serial

from harness.errors import LinkClosed, LinkError, LinkTimeout
from harness.link.base import DEFAULT_READ_SIZE, Link
from harness.link.ports import is_local_device, ports_present
from harness.options import DEFAULT_BAUD

_POLL_S = 0.001
#: pyserial drivers that refuse a write timeout ("write_timeout is currently not supported")
_NO_WRITE_TIMEOUT = frozenset({"serial.rfc2217"})


@dataclass(frozen=True)
class SerialOptions:
    baud: int = DEFAULT_BAUD
    write_timeout_s: float = 5.0
    low_latency: bool = True      # ASYNC_LOW_LATENCY where the driver supports it (Linux UARTs)
    exclusive: bool = True        # advisory flock on device files: two harnesses, one board


class SerialLink(Link):
    """A pyserial port. Build it with `SerialLink.open(url, baud, timeout)`."""

    def __init__(self, port: serial.SerialBase, url: str, options: SerialOptions) -> None:
        self._port: serial.SerialBase | None = port
        self.url = url
        self.options = options
        self._fileno = _fileno(port)
        # pyserial's own write timeout where the backend has one, else the emulation (module doc)
        self._writer = None if port.write_timeout is not None else _BoundedWriter(url)
        self._info: dict[str, Any] = {"name": url, "kind": "serial", "url": url, "baud": options.baud,
                                      "handler": f"{type(port).__module__}.{type(port).__name__}",
                                      "write_timeout_s": options.write_timeout_s,
                                      "write_timeout": "driver" if self._writer is None else "emulated",
                                      "wait": "select" if self._fileno is not None else "poll"}
        self._info.update(_set_low_latency(port, url) if options.low_latency else {"low_latency": False})

    @classmethod
    def open(cls, url: str, baud: int = DEFAULT_BAUD, timeout: float = 5.0, **kwargs: Any) -> SerialLink:
        """Open `url` (a device path or pyserial URL); `timeout` bounds writes. Options: SerialOptions."""
        options = SerialOptions(baud=baud, write_timeout_s=timeout, **kwargs)
        extra: dict[str, Any] = {}
        if _is_device_file(url):
            extra["exclusive"] = options.exclusive
        try:
            port = serial.serial_for_url(_driver_url(url), baudrate=baud, timeout=0, do_not_open=True, **extra)
            # Opening with a write timeout would fail only after the telnet negotiation (and a second
            # connection right after is refused by ser2net): decide by the driver before opening.
            native = type(port).__module__ not in _NO_WRITE_TIMEOUT
            port.write_timeout = options.write_timeout_s if native else None
            port.open()
        except (serial.SerialException, ValueError, OSError, NotImplementedError) as exc:
            # A wrong device path is the common bench mistake: say which ports there are.
            hint = f"; {ports_present()}" if is_local_device(url) else ""
            raise LinkError(f"could not open port {url} at {baud} baud: {exc}{hint}") from exc
        return cls(port, url, options)

    # ------------------------------------------------------------------------------ identity
    @property
    def name(self) -> str:
        return self.url

    @property
    def closed(self) -> bool:
        return self._port is None or not self._port.is_open

    @property
    def port(self) -> serial.SerialBase:
        if self._port is None:
            raise LinkClosed(f"{self.url}: link is closed")
        return self._port

    def info(self) -> dict[str, Any]:
        return dict(self._info)

    # ---------------------------------------------------------------------------------- I/O
    def write(self, data: bytes) -> None:
        port = self.port
        try:
            if self._writer is None:
                written = port.write(data)  # no flush(): tcdrain() has no timeout
            else:
                written = self._writer.write(port, data, self.options.write_timeout_s)
        except (serial.SerialTimeoutException, _WriteStuck) as exc:
            if isinstance(exc, _WriteStuck):
                self.close()      # unblocks the helper thread; the link is unusable anyway
            raise LinkTimeout(f"{self.url}: write did not complete within {self.options.write_timeout_s:.2f} s",
                              waited_s=self.options.write_timeout_s) from exc
        except (serial.SerialException, OSError) as exc:
            if isinstance(exc.__context__, socket.timeout) or isinstance(exc, socket.timeout):
                # the driver's own socket timeout (RFC 2217: 5 s) hit first: still a stuck peer
                raise LinkTimeout(f"{self.url}: write made no progress: {exc}") from exc
            raise LinkClosed(f"{self.url}: write failed: {exc}") from exc
        if written is not None and written != len(data):
            raise LinkTimeout(f"{self.url}: wrote {written} of {len(data)} bytes",
                              pending_bytes=len(data) - written)

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.0) -> bytes:
        port = self.port
        deadline = time.monotonic() + max(0.0, timeout)
        try:
            while True:
                data = port.read(max_bytes)  # timeout 0: what is there, up to max_bytes
                if data:
                    return bytes(data)
                left = deadline - time.monotonic()
                if left <= 0:
                    return b""
                if self._fileno is not None:
                    select.select([self._fileno], [], [], left)
                else:
                    time.sleep(min(_POLL_S, left))
        except (serial.SerialException, OSError) as exc:
            raise LinkClosed(f"{self.url}: read failed: {exc}") from exc

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass
        if self._writer is not None:
            self._writer.stop()


class _WriteStuck(Exception):
    """The emulated write timeout expired (the helper thread is still blocked in the driver)."""


class _BoundedWriter:
    """A write timeout for drivers without one: writes run in one helper thread, the caller waits with
    a deadline. Jobs are handed over one at a time (the link is not shared between threads)."""

    def __init__(self, name: str) -> None:
        self._cv = threading.Condition()
        self._job: tuple[serial.SerialBase, bytes] | None = None
        self._done = False
        self._result: int | None = None
        self._error: BaseException | None = None
        self._stopped = False
        self._thread = threading.Thread(target=self._loop, name=f"uwb-hil writer {name}", daemon=True)
        self._thread.start()

    def write(self, port: serial.SerialBase, data: bytes, timeout_s: float) -> int | None:
        with self._cv:
            if self._job is not None:
                raise _WriteStuck("a previous write is still blocked")
            self._job, self._done, self._error = (port, data), False, None
            self._cv.notify_all()
            if not self._cv.wait_for(lambda: self._done, timeout=max(0.0, timeout_s)):
                raise _WriteStuck(f"no completion within {timeout_s:.2f} s")
            if self._error is not None:
                raise self._error
            return self._result

    def stop(self) -> None:
        with self._cv:
            self._stopped = True
            self._cv.notify_all()

    def _loop(self) -> None:
        while True:
            with self._cv:
                self._cv.wait_for(lambda: self._stopped or self._job is not None)
                if self._job is None:
                    return
                port, data = self._job
            result: int | None = None
            error: BaseException | None = None
            try:
                result = port.write(data)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller, which classifies it
                error = exc
            with self._cv:
                self._job, self._result, self._error, self._done = None, result, error, True
                self._cv.notify_all()


def _driver_url(url: str) -> str:
    """The URL handed to pyserial. RFC 2217: the harness never relies on the modem lines, so it does not
    wait for the server to acknowledge DTR/RTS (`ign_set_control`; still sent): a server whose port
    cannot set them (ser2net on a pty, some USB CDC bridges) never answers and the open would fail."""
    if not url.startswith("rfc2217://"):
        return url
    parts = urlsplit(url)
    if "ign_set_control" in parse_qs(parts.query, keep_blank_values=True):
        return url
    return urlunsplit(parts._replace(query="&".join(q for q in (parts.query, "ign_set_control") if q)))


def _is_device_file(url: str) -> bool:
    return "://" not in url


def _fileno(port: serial.SerialBase) -> int | None:
    try:
        fd = getattr(port, "fileno")()
    except (AttributeError, NotImplementedError, OSError, serial.SerialException):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def _set_low_latency(port: serial.SerialBase, url: str) -> dict[str, Any]:
    """Ask for ASYNC_LOW_LATENCY and record what the driver said (and the FTDI latency timer)."""
    out: dict[str, Any] = {}
    setter = getattr(port, "set_low_latency_mode", None)
    if setter is None or not _is_device_file(url):
        out["low_latency"] = None
        out["low_latency_note"] = "not applicable to this transport"
    else:
        try:
            setter(True)
            out["low_latency"] = True
        except (ValueError, NotImplementedError, OSError) as exc:
            out["low_latency"] = False
            out["low_latency_note"] = str(exc)
    timer = _latency_timer_ms(url)
    if timer is not None:
        out["latency_timer_ms"] = timer
    return out


def _latency_timer_ms(url: str) -> int | None:
    """USB-serial adapters (FTDI) batch input for this many ms (default 16); 1 is best for HIL."""
    if not _is_device_file(url):
        return None
    dev = Path(url).resolve().name
    path = Path("/sys/bus/usb-serial/devices") / dev / "latency_timer"
    try:
        return int(path.read_text().strip())
    except (OSError, ValueError):
        return None
