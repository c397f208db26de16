"""The host end of QEMU's link to the guest: its USART on a unix socket (or the pty of the older recipe), or
the two FIFOs of the semihosting link (the emulator build's SYS_READ/SYS_WRITE, docs/qemu.md). A transport like
the others in harness/link/; the QEMU process is harness/device/qemu_process.py, the device
harness/device/qemu.py.
"""

from __future__ import annotations

import errno
import os
import select
from typing import Any

from harness.errors import LinkClosed, LinkTimeout
from harness.link.base import DEFAULT_READ_SIZE, Link, write_fd

#: how each host end moves bytes (Link.info()["transport"])
_TRANSPORTS = {"unix": "QEMU -serial socket (USART, ~65 us per byte)",
               "pty": "QEMU -serial pty (USART, ~65 us per byte)",
               "semihosting": "ARM semihosting SYS_READ/SYS_WRITE on two FIFOs (whole blocks per trap)"}


class QemuPtyLink(Link):
    """The host end of QEMU's link: the pty or socket of the guest's USART (one fd), or the semihosting link's
    FIFOs (`write_fd`: the one the guest reads; `fd`: the one it writes). The fds belong to QemuProcess.

    QEMU's USART transmits synchronously: a guest byte written while the host side of the pty is full
    stalls the guest CPU until the host reads (the semihosting guest likewise blocks in SYS_WRITE on a full
    FIFO). A host blocked in write() (the guest is not taking its input) would then wait for a guest that
    waits for the host. So while a write cannot progress, it drains what the guest sent into a buffer that
    read() returns first; the buffer is bounded."""

    def __init__(self, fd: int, path: str, write_timeout_s: float = 10.0, max_buffered: int = 64 << 20,
                 write_fd: int | None = None) -> None:
        self._fd: int | None = fd
        self._wfd = write_fd if write_fd is not None and write_fd >= 0 else fd
        self._path = path
        self._kind = path.split(":", 1)[0] if path.startswith(("unix:", "semihosting:")) else "pty"
        self.write_timeout_s = write_timeout_s
        self.max_buffered = max_buffered
        self._rx = bytearray()

    @property
    def name(self) -> str:
        return f"qemu-{'socket' if self._kind == 'unix' else self._kind}:{self._path}"

    @property
    def closed(self) -> bool:
        return self._fd is None

    def _require(self) -> int:
        if self._fd is None:
            raise LinkClosed(f"{self.name} is closed")
        return self._fd

    def write(self, data: bytes) -> None:
        fd = self._require()

        def stalled(pending: int, waited: float) -> LinkTimeout:
            return LinkTimeout(f"{self.name}: no byte accepted for {waited:.1f} s ({pending} pending): "
                               "the guest stopped reading", pending_bytes=pending, waited_s=waited)

        def wait(left: float) -> None:     # drain the guest's output, or QEMU's USART stalls the guest
            r, _, _ = select.select([fd], [self._wfd], [], min(0.05, left))
            if r:
                self._drain(fd)

        write_fd(self._wfd, data, self.write_timeout_s, lambda exc: LinkClosed(f"{self.name}: write failed: {exc}"),
                 stalled, wait)

    def _drain(self, fd: int) -> None:
        """Move what the guest sent into the buffer (called while a write waits)."""
        if len(self._rx) >= self.max_buffered:
            raise LinkTimeout(f"{self.name}: {len(self._rx)} bytes from the guest unread while writing: "
                              "the host is not reading its replies", pending_bytes=len(self._rx), waited_s=0.0)
        chunk = self._read_fd(fd, DEFAULT_READ_SIZE)
        self._rx += chunk

    def _read_fd(self, fd: int, max_bytes: int) -> bytes:
        """Called when select() found fd readable: no bytes then is end of file (the socket's peer is gone)."""
        try:
            data = os.read(fd, max_bytes)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                raise LinkClosed(f"{self.name}: closed (QEMU exited)") from exc
            raise LinkClosed(f"{self.name}: read failed: {exc}") from exc
        if not data and max_bytes > 0:
            raise LinkClosed(f"{self.name}: closed (QEMU exited)")
        return data

    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.0) -> bytes:
        fd = self._require()
        if self._rx:
            out = bytes(self._rx[:max_bytes])
            del self._rx[:max_bytes]
            return out
        r, _, _ = select.select([fd], [], [], max(0.0, timeout))
        if not r:
            return b""
        return self._read_fd(fd, max_bytes)

    def close(self) -> None:
        self._fd = None  # the fd itself belongs to QemuProcess

    def info(self) -> dict[str, Any]:
        return {"name": self.name, "transport": _TRANSPORTS[self._kind]}
