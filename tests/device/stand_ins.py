"""Stand-ins for a device, shared by tests/device/test_device.py and test_pytest_plugin.py: a protocol-speaking
stand-in firmware started the way uwb-fw is (`--tty <slave>`, HELLO answered from Python), and a 'board'
behind socket:// (`FakeBoard`, on `OneClientServer`, also test_link.py's echo server); with their fixtures `fake_fw` and `board`."""

from __future__ import annotations

import socket
import stat
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from protocol import PROTOCOL_VERSION
from protocol.framing import FrameDecoder, encode_frame
from protocol.messages import Hello, HelloReply

FAKE_HASH = 0x0123456789ABCDEF

# A stand-in firmware: serves HELLO on the tty it is given. Options after the tty:
#   --proto N            protocol version to report
#   --ignore-first       do not answer the first HELLO (a board still booting)
#   --noise              send garbage and a HELLO_REPLY with a wrong nonce before the real one
#   --exit-after-hello N exit with code N right after answering
# The model hash comes from $FAKE_MODEL_HASH (hex) when set.
FAKE_FIRMWARE = r'''
import argparse, os, sys
from protocol.framing import FrameDecoder, encode_frame
from protocol.messages import Hello, HelloReply

ap = argparse.ArgumentParser()
ap.add_argument("--tty", required=True)
ap.add_argument("--proto", type=int, default=None)
ap.add_argument("--ignore-first", action="store_true")
ap.add_argument("--noise", action="store_true")
ap.add_argument("--exit-after-hello", type=int, default=None)
a = ap.parse_args()
from protocol import PROTOCOL_VERSION
proto = PROTOCOL_VERSION if a.proto is None else a.proto
model_hash = int(os.environ.get("FAKE_MODEL_HASH", "%x" % FAKE_HASH), 16)
fd = os.open(a.tty, os.O_RDWR | os.O_NOCTTY)
print("fake firmware serving", a.tty, file=sys.stderr, flush=True)
dec, seen = FrameDecoder(), 0
while True:
    try:
        data = os.read(fd, 4096)
    except OSError:
        break
    if not data:
        break
    for frame in dec.feed(data):
        if not isinstance(frame.msg, Hello):
            continue
        seen += 1
        if a.ignore_first and seen == 1:
            continue
        out = b""
        if a.noise:
            out += b"\x13\x37garbage\x00" + encode_frame(HelloReply(frame.msg.nonce ^ 1, proto, 0, 0, 0, 0, 0, 0, 0,
                                                                     b"stale", b"fake"), 7)
        out += encode_frame(HelloReply(frame.msg.nonce, proto, 1, 2, 3, 0, 1, 2, model_hash, b"fake-id", b"fake"),
                            frame.seq)
        os.write(fd, out)
        if a.exit_after_hello is not None:
            print("fake firmware: exiting on purpose", file=sys.stderr, flush=True)
            sys.exit(a.exit_after_hello)
'''.replace("FAKE_HASH", str(FAKE_HASH))


def write_script(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture
def fake_fw(tmp_path: Path) -> Path:
    return write_script(tmp_path, "fake-fw", f"#!{sys.executable}\n{FAKE_FIRMWARE}")


class OneClientServer:
    """A TCP server on 127.0.0.1 serving one client from a thread: `serve(conn, data)` answers each block
    received (`greet(conn)` first); `stop()` hangs up on the client, `close()` also closes the server."""

    def __init__(self) -> None:
        self._srv = socket.create_server(("127.0.0.1", 0))
        self._srv.settimeout(5.0)
        self.port = self._srv.getsockname()[1]
        self.url = f"socket://127.0.0.1:{self.port}"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def greet(self, conn: socket.socket) -> None:
        """Sent on connection, before anything is received."""

    def serve(self, conn: socket.socket, data: bytes) -> None:
        raise NotImplementedError

    def _run(self) -> None:
        try:
            conn, _ = self._srv.accept()
        except OSError:
            return
        conn.settimeout(0.05)
        with conn:
            self.greet(conn)
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                self.serve(conn, data)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def close(self) -> None:
        self.stop()
        self._srv.close()


class FakeBoard(OneClientServer):
    """A 'board' behind socket://: answers HELLO over TCP from a thread."""

    def __init__(self, stale: bytes = b"") -> None:
        self._stale = stale
        self._dec = FrameDecoder()
        super().__init__()

    def greet(self, conn: socket.socket) -> None:
        if self._stale:
            conn.sendall(self._stale)

    def serve(self, conn: socket.socket, data: bytes) -> None:
        for f in self._dec.feed(data):
            if isinstance(f.msg, Hello):
                conn.sendall(encode_frame(HelloReply(f.msg.nonce, PROTOCOL_VERSION, 0, 9, 0, 1, 0, 0, 7,
                                                     b"board", b"stm32"), f.seq))


@pytest.fixture
def board() -> Iterator[FakeBoard]:
    b = FakeBoard(stale=b"boot log line\r\n" * 4)
    yield b
    b.close()
