"""`SerialLink`: any pyserial port or URL (/dev/tty*, rfc2217://, socket://, loop://, spy://, ...).

The pyserial object is kept non-blocking (timeout 0): read() waits with select() on its fd where it
has one (device files, socket://, spy://) and polls `in_waiting` otherwise (loop://, rfc2217://),
so a read returns as soon as data is there and changing the wait never re-configures the port
(pyserial re-applies termios, or re-negotiates RFC 2217, on every timeout change).
Writes use pyserial's write timeout; a stuck peer raises LinkTimeout.
"""

from __future__ import annotations

import select
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from harness.errors import LinkClosed, LinkError, LinkTimeout
from harness.link.base import DEFAULT_READ_SIZE, Link

_POLL_S = 0.001


@dataclass(frozen=True)
class SerialOptions:
    baud: int = 115200
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
        self._info: dict[str, Any] = {"name": url, "kind": "serial", "url": url, "baud": options.baud,
                                      "handler": f"{type(port).__module__}.{type(port).__name__}",
                                      "write_timeout_s": options.write_timeout_s,
                                      "wait": "select" if self._fileno is not None else "poll"}
        self._info.update(_set_low_latency(port, url) if options.low_latency else {"low_latency": False})

    @classmethod
    def open(cls, url: str, baud: int = 115200, timeout: float = 5.0, **kwargs: Any) -> SerialLink:
        """Open `url` (a device path or pyserial URL); `timeout` bounds writes. Options: SerialOptions."""
        options = SerialOptions(baud=baud, write_timeout_s=timeout, **kwargs)
        extra: dict[str, Any] = {}
        if _is_device_file(url):
            extra["exclusive"] = options.exclusive
        try:
            port = serial.serial_for_url(url, baudrate=baud, timeout=0, write_timeout=options.write_timeout_s,
                                         **extra)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise LinkError(f"cannot open {url} at {baud} baud: {exc}") from exc
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
            written = port.write(data)  # no flush(): tcdrain() has no timeout
        except serial.SerialTimeoutException as exc:
            raise LinkTimeout(f"{self.url}: write did not complete within {self.options.write_timeout_s:.2f} s",
                              waited_s=self.options.write_timeout_s) from exc
        except (serial.SerialException, OSError) as exc:
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
