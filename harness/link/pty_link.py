"""`PtyPair`: a pseudo-terminal whose master end is the harness's link and whose slave path is
handed to the device (`uwb-fw --tty /dev/pts/N`).

Pitfalls handled here (see shared/reference/hil-harness-conventions.md, section 5):
  * the line discipline lives on the SLAVE: it is made raw (no echo, no CR/LF mapping, no signals,
    no flow control, 8 bit) right after openpty(), before its path is published, so no byte is
    ever cooked;
  * Linux reports the end of the slave side as EIO on the master (BSD: read() == 0); both become
    LinkClosed. Pending data is returned first. Reads use os.read (no buffered file objects);
  * the master is non-blocking: a device that stops reading fills the ~20 KiB kernel buffer and a
    write raises LinkTimeout after `write_timeout_s` without progress instead of hanging;
  * the harness holds its own slave fd until `release_slave()`, so the master does not report EIO
    before the device has opened the slave. A device started with `pass_fds=(pair.slave_fd,)` holds
    the slave from fork() on; the harness then releases its copy and the device's exit shows up
    at once as LinkClosed.
"""

from __future__ import annotations

import errno
import os
import select
import termios
import time
import tty
from dataclasses import dataclass
from typing import Any

from harness.errors import LinkClosed, LinkTimeout
from harness.link.base import DEFAULT_READ_SIZE, Link, write_fd


@dataclass(frozen=True)
class PtyOptions:
    write_timeout_s: float = 5.0   # a write fails when no byte could be written for this long


def make_raw(fd: int) -> None:
    """cfmakeraw() on a tty fd: 8N1, no echo, no canonical mode, no translation, no flow control."""
    tty.setraw(fd, termios.TCSANOW)
    iflag, oflag, cflag, lflag, ispeed, ospeed, cc = termios.tcgetattr(fd)
    iflag &= ~(termios.IGNBRK | termios.BRKINT | termios.PARMRK | termios.ISTRIP | termios.INLCR
               | termios.IGNCR | termios.ICRNL | termios.IXON | termios.IXOFF | termios.IXANY)
    oflag &= ~termios.OPOST
    lflag &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    cflag &= ~(termios.CSIZE | termios.PARENB | termios.CSTOPB)
    cflag |= termios.CS8 | termios.CREAD | termios.CLOCAL
    cc = list(cc)
    cc[termios.VMIN] = 1
    cc[termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, [iflag, oflag, cflag, lflag, ispeed, ospeed, cc])


class PtyPair(Link):
    """A raw pty. The harness reads and writes the master; the device gets `slave_path`."""

    def __init__(self, options: PtyOptions = PtyOptions()) -> None:
        self.options = options
        master, slave = os.openpty()
        try:
            make_raw(slave)
            os.set_blocking(master, False)
            self.slave_path: str = os.ttyname(slave)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        self._master: int | None = master
        self._slave: int | None = slave

    # ------------------------------------------------------------------------------- identity
    @property
    def name(self) -> str:
        return f"pty:{self.slave_path}"

    @property
    def closed(self) -> bool:
        return self._master is None

    @property
    def master_fd(self) -> int:
        if self._master is None:
            raise LinkClosed(f"{self.name}: link is closed")
        return self._master

    @property
    def slave_fd(self) -> int | None:
        """The harness's own slave fd (None once released)."""
        return self._slave

    def release_slave(self) -> None:
        """Close the harness's slave fd: from now on the master sees EIO once the device closes it."""
        slave, self._slave = self._slave, None
        if slave is not None:
            os.close(slave)

    def info(self) -> dict[str, Any]:
        return {"name": self.name, "kind": "pty", "slave": self.slave_path,
                "write_timeout_s": self.options.write_timeout_s}

    # ------------------------------------------------------------------------------------ I/O
    def write(self, data: bytes) -> None:
        fd = self.master_fd

        def stalled(pending: int, waited: float) -> LinkTimeout:
            return LinkTimeout(f"{self.name}: no byte written for {waited:.2f} s, {pending} of {len(data)} "
                               f"bytes pending: the device stopped reading", pending_bytes=pending, waited_s=waited)

        def wait(left: float) -> None:
            select.select([], [fd], [], min(left, 0.1))

        write_fd(fd, data, self.options.write_timeout_s, lambda exc: self._closed_by(exc, "write"), stalled, wait)

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.0) -> bytes:
        fd = self.master_fd
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            if ready:
                try:
                    data = os.read(fd, max_bytes)
                except BlockingIOError:
                    data = None  # spurious wake-up
                except OSError as exc:
                    raise self._closed_by(exc, "read") from exc
                if data == b"":
                    raise LinkClosed(f"{self.name}: end of file (the device closed the tty)")
                if data:
                    return data
            if time.monotonic() >= deadline:
                return b""

    def close(self) -> None:
        self.release_slave()
        master, self._master = self._master, None
        if master is not None:
            os.close(master)

    def _closed_by(self, exc: OSError, what: str) -> LinkClosed:
        if exc.errno == errno.EIO:
            return LinkClosed(f"{self.name}: the device side of the pty is closed (EIO on {what})")
        return LinkClosed(f"{self.name}: {what} failed: {exc}")

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: nothing useful to do
            pass
