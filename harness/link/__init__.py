"""Byte transports between the harness and a device: a raw pty pair or any pyserial port/URL."""

from __future__ import annotations

from harness.link.base import Link
from harness.link.pty_link import PtyOptions, PtyPair, make_raw
from harness.link.serial_link import SerialLink, SerialOptions
from harness.options import DEFAULT_BAUD


def open_link(url_or_path: str, baud: int = DEFAULT_BAUD, timeout: float = 5.0) -> Link:
    """Open a board's port: a device path (/dev/ttyACM0, /dev/pts/N) or a pyserial URL
    (rfc2217://host:port, socket://host:port, loop://, spy://...). `timeout` bounds writes."""
    return SerialLink.open(url_or_path, baud=baud, timeout=timeout)


__all__ = ["Link", "PtyOptions", "PtyPair", "SerialLink", "SerialOptions", "make_raw", "open_link"]
