"""`Link`: a byte transport between the harness and a device. No framing, no device knowledge.

Contract of every implementation:
  write(data)                  all of `data` or LinkTimeout (no progress within the write timeout)
                               or LinkClosed; never blocks forever;
  read(max_bytes, timeout)     what is available (at least 1 byte) as soon as it is, or b"" when
                               `timeout` seconds passed without data; LinkClosed at end of stream;
  close()                      idempotent.
"""

from __future__ import annotations

import os
import time
from abc import ABC, abstractmethod
from types import TracebackType
from typing import Any, Callable

from harness.errors import LinkClosed, LinkTimeout

DEFAULT_READ_SIZE = 65536


def write_fd(fd: int, data: bytes, timeout_s: float, closed: Callable[[OSError], LinkClosed],
             stalled: Callable[[int, float], LinkTimeout], wait: Callable[[float], None]) -> None:
    """Write all of `data` to a non-blocking fd. While it takes nothing, `wait(seconds left)` waits (for
    it to become writable, or does what the transport must meanwhile); after `timeout_s` without a byte
    taken, `stalled(bytes pending, seconds waited)` is raised; an OSError becomes `closed(exc)`."""
    view = memoryview(data)
    last_progress = time.monotonic()
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            raise closed(exc) from exc
        if n:
            view = view[n:]
            last_progress = time.monotonic()
            continue
        waited = time.monotonic() - last_progress
        if waited >= timeout_s:
            raise stalled(len(view), waited)
        wait(timeout_s - waited)


class Link(ABC):
    """Byte transport. Use as a context manager to close it reliably."""

    @property
    @abstractmethod
    def name(self) -> str:
        """Human-readable endpoint, e.g. 'pty:/dev/pts/4' or 'socket://127.0.0.1:5000'."""

    @property
    @abstractmethod
    def closed(self) -> bool: ...

    @abstractmethod
    def write(self, data: bytes) -> None: ...

    @abstractmethod
    def read(self, max_bytes: int = DEFAULT_READ_SIZE, timeout: float = 0.0) -> bytes: ...

    @abstractmethod
    def close(self) -> None: ...

    def info(self) -> dict[str, Any]:
        """Transport settings worth recording in a report (latency depends on them)."""
        return {"name": self.name}

    def discard_input(self, quiet_s: float = 0.0, max_s: float = 1.0) -> int:
        """Throw away pending input until the line was quiet for `quiet_s` (bounded by `max_s`)."""
        dropped = 0
        deadline = time.monotonic() + max_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return dropped
            chunk = self.read(DEFAULT_READ_SIZE, min(quiet_s, left))
            if not chunk:
                return dropped
            dropped += len(chunk)

    def __enter__(self) -> Link:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name}{' closed' if self.closed else ''}>"
