"""`SerialDevice`: a board that is already running, reached through a serial port or pyserial URL.

The harness cannot see the board's process: `alive()` only says whether the link is open, and a
silent board surfaces as DeviceTimeout (never DeviceDied).
"""

from __future__ import annotations

from dataclasses import dataclass

from harness.device.base import Device
from harness.link.base import Link
from harness.link.serial_link import SerialLink
from harness.options import DEFAULT_BAUD


@dataclass(frozen=True)
class SerialDeviceOptions:
    write_timeout_s: float = 5.0
    discard_quiet_s: float = 0.05   # at start: drop stale input until the line is quiet this long
    discard_max_s: float = 0.5      # ... but for at most this long (a chatty board never goes quiet)


class SerialDevice(Device):
    """A running board on `url` (/dev/ttyACM0, rfc2217://host:port, socket://host:port, ...)."""

    def __init__(self, url: str, baud: int = DEFAULT_BAUD,
                 options: SerialDeviceOptions = SerialDeviceOptions()) -> None:
        super().__init__()
        self.url = url
        self.baud = baud
        self.options = options
        self._link: SerialLink | None = None
        self.discarded_bytes = 0

    @property
    def name(self) -> str:
        return f"board {self.url}"

    @property
    def link(self) -> Link:
        return self._running(self._link)

    def start(self) -> None:
        self._not_running(self._link)
        link = SerialLink.open(self.url, baud=self.baud, timeout=self.options.write_timeout_s)
        try:
            self.discarded_bytes = link.discard_input(self.options.discard_quiet_s, self.options.discard_max_s)
        except BaseException:
            link.close()
            raise
        self._link = link

    def stop(self) -> int | None:
        link, self._link = self._link, None
        if link is not None:
            link.close()
        return None

    def alive(self) -> bool:
        return self._link is not None and not self._link.closed
