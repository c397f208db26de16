"""Byte transports: raw pty pair (with real child processes on the slave) and pyserial URLs."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import termios
import time
from collections.abc import Iterator

import pytest

from harness.errors import LinkClosed, LinkError, LinkTimeout
from harness.link import Link, PtyOptions, PtyPair, SerialLink, open_link
from stand_ins import OneClientServer

pytestmark = pytest.mark.timeout(60)

ALL_BYTES = bytes(range(256))
# Reads the slave path given as argv[1] and writes every byte back until EOF/EIO.
ECHO_CHILD = r"""
import os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
while True:
    try:
        data = os.read(fd, 4096)
    except OSError:
        break
    if not data:
        break
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
"""


def read_exactly(link: Link, n: int, timeout: float = 5.0) -> bytes:
    deadline = time.monotonic() + timeout
    buf = b""
    while len(buf) < n and time.monotonic() < deadline:
        buf += link.read(n - len(buf), max(0.0, deadline - time.monotonic()))
    return buf


@pytest.fixture
def pair() -> Iterator[PtyPair]:
    with PtyPair(PtyOptions(write_timeout_s=0.3)) as p:
        yield p


def _start_echo(pair: PtyPair, kind: str) -> subprocess.Popen[bytes]:
    if kind == "python":
        return subprocess.Popen([sys.executable, "-c", ECHO_CHILD, pair.slave_path],
                                stdin=subprocess.DEVNULL, start_new_session=True)
    slave = pair.slave_fd
    assert slave is not None
    # `cat` with the (already raw) slave as stdin and stdout
    return subprocess.Popen(["cat"], stdin=slave, stdout=slave, start_new_session=True)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(5)


# --------------------------------------------------------------------------------------- pty
def test_slave_is_raw_before_anyone_uses_it(pair: PtyPair) -> None:
    assert pair.slave_fd is not None
    iflag, oflag, cflag, lflag, _, _, cc = termios.tcgetattr(pair.slave_fd)
    assert not lflag & (termios.ECHO | termios.ICANON | termios.ISIG | termios.IEXTEN)
    assert not oflag & termios.OPOST
    assert not iflag & (termios.ICRNL | termios.INLCR | termios.IGNCR | termios.IXON | termios.ISTRIP)
    assert cflag & termios.CSIZE == termios.CS8
    assert cc[termios.VMIN] == 1


def test_pty_passes_bytes_unchanged_both_ways_without_echo(pair: PtyPair) -> None:
    slave = pair.slave_fd
    assert slave is not None
    pair.write(ALL_BYTES)
    got = b""
    deadline = time.monotonic() + 2
    while len(got) < 256 and time.monotonic() < deadline:
        got += os.read(slave, 4096)
    assert got == ALL_BYTES
    assert pair.read(4096, 0.05) == b""          # nothing echoed back to the master
    os.write(slave, b"a\nb\r\x03\x11\x13" + ALL_BYTES)
    assert read_exactly(pair, 7 + 256) == b"a\nb\r\x03\x11\x13" + ALL_BYTES  # no ONLCR, no ISIG/IXON


@pytest.mark.parametrize("kind", ["python", "cat"])
def test_all_byte_values_round_trip_through_an_echo_child(pair: PtyPair, kind: str) -> None:
    proc = _start_echo(pair, kind)
    try:
        payload = ALL_BYTES * 8 + bytes(reversed(ALL_BYTES)) * 8
        pair.write(payload)
        assert read_exactly(pair, len(payload)) == payload
    finally:
        _stop(proc)


def test_eio_after_the_last_slave_fd_closes_is_link_closed(pair: PtyPair) -> None:
    pair.release_slave()
    start = time.monotonic()
    with pytest.raises(LinkClosed, match="EIO"):
        pair.read(100, 2.0)
    assert time.monotonic() - start < 1.0


def test_pending_output_of_an_exited_child_is_read_before_link_closed(pair: PtyPair) -> None:
    code = "import os,sys; fd=os.open(sys.argv[1], os.O_RDWR|os.O_NOCTTY); os.write(fd, b'last words\\n')"
    proc = subprocess.Popen([sys.executable, "-c", code, pair.slave_path])
    proc.wait(10)
    pair.release_slave()
    assert read_exactly(pair, 11, 2.0) == b"last words\n"
    with pytest.raises(LinkClosed):
        pair.read(100, 2.0)


@pytest.mark.parametrize("timeout", [0.0, 0.05, 0.3])
def test_read_timeout_returns_empty_in_bounded_time(pair: PtyPair, timeout: float) -> None:
    start = time.monotonic()
    assert pair.read(100, timeout) == b""
    elapsed = time.monotonic() - start
    assert timeout - 0.01 <= elapsed < timeout + 0.2


def test_write_to_a_device_that_stops_reading_raises_link_timeout(pair: PtyPair) -> None:
    start = time.monotonic()
    with pytest.raises(LinkTimeout) as info:
        pair.write(b"\x55" * (1 << 20))  # far more than the kernel buffers
    elapsed = time.monotonic() - start
    assert 0.25 < elapsed < 2.0
    assert info.value.pending_bytes and info.value.pending_bytes > 0


def test_closed_pty_raises_link_closed_and_close_is_idempotent() -> None:
    pair = PtyPair()
    pair.close()
    pair.close()
    assert pair.closed
    with pytest.raises(LinkClosed):
        pair.read(1, 0.0)
    with pytest.raises(LinkClosed):
        pair.write(b"x")


def test_pty_name_and_info(pair: PtyPair) -> None:
    assert pair.name == f"pty:{pair.slave_path}"
    assert pair.slave_path.startswith("/dev/")
    assert pair.info()["kind"] == "pty"


# ------------------------------------------------------------------------------- pyserial
def test_serial_loop_url_round_trip_and_timeout() -> None:
    with open_link("loop://", 115200, timeout=1.0) as link:
        assert isinstance(link, SerialLink)
        link.write(ALL_BYTES)
        assert read_exactly(link, 256) == ALL_BYTES
        start = time.monotonic()
        assert link.read(10, 0.1) == b""
        assert 0.09 <= time.monotonic() - start < 0.4
        info = link.info()
        assert info["url"] == "loop://" and info["baud"] == 115200
        assert "low_latency" in info
    assert link.closed
    with pytest.raises(LinkClosed):
        link.read(1, 0.0)


class EchoServer(OneClientServer):
    """TCP echo on 127.0.0.1 (one client), in a thread; `close_client()` hangs up on it."""

    def serve(self, conn: socket.socket, data: bytes) -> None:
        conn.sendall(data)

    def close_client(self) -> None:
        self.stop()


@pytest.fixture
def echo_server() -> Iterator[EchoServer]:
    srv = EchoServer()
    yield srv
    srv.close()


def test_serial_socket_url_round_trip(echo_server: EchoServer) -> None:
    with open_link(f"socket://127.0.0.1:{echo_server.port}", 115200) as link:
        payload = ALL_BYTES * 16
        link.write(payload)
        assert read_exactly(link, len(payload)) == payload
        assert link.info()["wait"] == "select"
        start = time.monotonic()
        assert link.read(10, 0.1) == b""
        assert time.monotonic() - start < 0.4


def test_serial_socket_hang_up_is_link_closed(echo_server: EchoServer) -> None:
    with open_link(f"socket://127.0.0.1:{echo_server.port}", 115200) as link:
        link.write(b"ping")
        assert read_exactly(link, 4) == b"ping"
        echo_server.close_client()
        with pytest.raises(LinkClosed):
            link.read(10, 2.0)


def test_serial_link_on_a_pty_device_path_records_low_latency(pair: PtyPair) -> None:
    with open_link(pair.slave_path, 115200) as link:
        info = link.info()
        assert info["low_latency"] is False  # ptys refuse TIOCSSERIAL; recorded, not fatal
        assert info["low_latency_note"]
        link.write(ALL_BYTES)
        assert read_exactly(pair, 256) == ALL_BYTES
        pair.write(ALL_BYTES)
        assert read_exactly(link, 256) == ALL_BYTES


def test_open_link_on_a_missing_device_is_a_link_error() -> None:
    # the message lists the ports present (or says there are none): the usual mistake is the device path
    with pytest.raises(LinkError, match=r"could not open port /dev/does-not-exist-uwb .*(ports present: |no serial "
                                        r"ports found on this machine)"):
        open_link("/dev/does-not-exist-uwb", 115200)
