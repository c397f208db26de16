"""Remote links and hostile peers.

* `rfc2217://` through a real ser2net (Debian package, installed by scripts/ensure_ser2net.sh from
  `make test`) serving the host firmware on a pty: a short flight via the CLI and via the pytest plugin's
  `--uwb-port`, and the emulated write timeout when the firmware stops reading.
* `--timeout` holds while a peer floods the link with bytes or with valid frames that are not the reply.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from harness.config import EstimatorConfig
from harness.device.channel import DeviceChannel
from harness.errors import DeviceTimeout, LinkTimeout
from harness.flight.scenarios import scenario_flight
from harness.link import PtyOptions, PtyPair, SerialLink, make_raw
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE, REPO_ROOT
from harness.stream.streamer import Pacing, Streamer
from protocol import encode_frame
from protocol import messages as m

pytestmark = pytest.mark.timeout(120)

SER2NET = shutil.which("ser2net")
UWB_HIL = [sys.executable, "-m", "harness.cli"]


# ------------------------------------------------------------------------------------ ser2net
@dataclass
class Ser2net:
    url: str
    firmware: subprocess.Popen[bytes]
    server: subprocess.Popen[bytes]
    log: Path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_listening(port: int, proc: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"ser2net exited with {proc.returncode}")
        # /proc/net/tcp: a listening socket on the port (connecting would take ser2net's one client)
        text = Path("/proc/net/tcp").read_text()
        if any(f":{port:04X} 00000000:0000 0A" in line for line in text.splitlines()):
            return
        time.sleep(0.05)
    raise RuntimeError(f"ser2net did not listen on {port} within {timeout} s")


@pytest.fixture
def ser2net(tmp_path: Path) -> Iterator[Ser2net]:
    """The host firmware on a pty (stdio = master), ser2net serving the slave as RFC 2217 on 127.0.0.1."""
    if SER2NET is None:
        pytest.skip("ser2net not installed (scripts/ensure_ser2net.sh installs it: root or sudo + apt-get)")
    if not DEFAULT_FIRMWARE.exists():
        pytest.skip(f"{DEFAULT_FIRMWARE} not built (make firmware)")
    master, slave = os.openpty()
    make_raw(slave)
    slave_path = os.ttyname(slave)
    port = _free_port()
    # ser2net 4 reads YAML (ser2net.yaml(5)); kickolduser: a new client replaces a stale one
    config = tmp_path / "ser2net.yaml"
    config.write_text("%YAML 1.1\n---\nconnection: &uwb\n"
                      f"    accepter: telnet(rfc2217),tcp,127.0.0.1,{port}\n"
                      "    enable: on\n    options:\n      kickolduser: true\n"
                      f"    connector: serialdev,{slave_path},115200n81,local\n")
    log = tmp_path / "ser2net.log"
    fw = subprocess.Popen([str(DEFAULT_FIRMWARE), "--stdio"], stdin=master, stdout=master,
                          stderr=open(tmp_path / "fw.log", "wb"), start_new_session=True)
    os.close(master)
    server = subprocess.Popen([SER2NET, "-n", "-d", "-c", str(config), "-P", str(tmp_path / "ser2net.pid")],
                              stdout=open(log, "wb"), stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _wait_listening(port, server)
        # The slave stays open here until the end: ser2net opens it only per client, and a pty whose
        # slave is closed by everyone gives the firmware EIO (it would exit between clients).
        yield Ser2net(f"rfc2217://127.0.0.1:{port}", fw, server, log)
    finally:
        for proc in (server, fw):
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGCONT)
                proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        os.close(slave)


def test_cli_flight_through_rfc2217(ser2net: Ser2net) -> None:
    t0 = time.monotonic()
    out = subprocess.run([*UWB_HIL, "run", "--port", ser2net.url, "--duration", "6", "--json", "--timeout", "5"],
                         capture_output=True, text=True, timeout=90, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stderr + ser2net.log.read_text()
    summary = json.loads(out.stdout)
    acc = summary["accuracy"]
    n = len(scenario_flight("circle", mode="twr", duration_s=6.0, seed=1).uwb)
    assert acc["accepted"] + acc["rejected_kinematic"] + acc["rejected_chi2"] == n
    assert summary["lost"] == 0
    assert acc["rmse"] < 0.2
    assert summary["device"]["target"] == "host"
    print(f"\nrfc2217 via ser2net: {n} measurements, RMSE {acc['rmse']:.3f} m, {time.monotonic() - t0:.1f} s")


def test_pytest_plugin_uwb_port_rfc2217(ser2net: Ser2net) -> None:
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:hypothesispytest",
                          "tests/device/test_end_to_end.py", "-k", "noiseless", "--uwb-port", ser2net.url],
                         capture_output=True, text=True, timeout=110, cwd=REPO_ROOT)
    assert out.returncode == 0, out.stdout[-3000:] + ser2net.log.read_text()
    assert "2 passed" in out.stdout, out.stdout[-2000:]


def test_rfc2217_write_timeout_is_emulated(ser2net: Ser2net) -> None:
    """pyserial's RFC 2217 driver refuses a write timeout: the link emulates it. With the firmware
    stopped, the pty, ser2net and TCP buffers fill up and a write must fail within the bound."""
    link = SerialLink.open(ser2net.url, baud=115200, timeout=1.0)
    try:
        assert link.info()["write_timeout"] == "emulated"
        os.kill(ser2net.firmware.pid, signal.SIGSTOP)
        chunk = bytes(64 * 1024)          # zeros: empty frames, ignored by the firmware
        worst = 0.0
        with pytest.raises(LinkTimeout, match="within 1.00 s"):
            for _ in range(2048):         # 128 MB: far more than every buffer on the way
                t0 = time.monotonic()
                try:
                    link.write(chunk)
                finally:
                    worst = max(worst, time.monotonic() - t0)
        assert worst < 2.0
        assert link.closed              # a write stuck in the driver leaves the link unusable: closed
    finally:
        link.close()
        os.kill(ser2net.firmware.pid, signal.SIGCONT)


# ------------------------------------------------------------------------------- flooding peer
class FloodPeer:
    """Writes `payload` back to back on `fd` (and drains what the harness sends) until stopped or
    `max_s` passed."""

    def __init__(self, fd: int, payload: bytes, max_s: float = 15.0) -> None:
        self.fd, self.payload, self.max_s = fd, payload, max_s
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def __enter__(self) -> FloodPeer:
        os.set_blocking(self.fd, False)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)

    def _loop(self) -> None:
        end = time.monotonic() + self.max_s
        while not self._stop.is_set() and time.monotonic() < end:
            r, w, _ = select.select([self.fd], [self.fd], [], 0.05)
            try:
                if r:
                    os.read(self.fd, 65536)
                if w:
                    self.sent += os.write(self.fd, self.payload)
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                return


GARBAGE = bytes(np.random.default_rng(1).integers(1, 256, 4096, dtype=np.uint8))      # no delimiter at all
UNRELATED = b"".join(encode_frame(m.HelloReply(nonce=7, proto_version=2, fw_major=0, fw_minor=1, fw_patch=0, cost_unit=0,
                                                    layout_twr=1, layout_tdoa=2, model_hash=1, build_id=b"flood",
                                                    target=b"flood"), i) for i in range(40))


# A separate process writing large blocks with blocking writes keeps the pty full: every read the
# harness makes returns data at once (a thread of this interpreter could not outpace it).
FLOOD_CHILD = r"""
import os, sys, time
fd = os.open(sys.argv[1], os.O_WRONLY | os.O_NOCTTY)
block = bytes.fromhex(sys.argv[2]) * (1 << 20 >> (len(sys.argv[2]) // 2).bit_length())
end = time.monotonic() + 15.0
while time.monotonic() < end:
    os.write(fd, block)
"""


@pytest.mark.parametrize("payload", [GARBAGE, UNRELATED], ids=["bytes", "valid-frames"])
def test_frame_channel_timeout_holds_while_peer_floods(payload: bytes) -> None:
    with PtyPair(PtyOptions(write_timeout_s=1.0)) as pair:
        child = subprocess.Popen([sys.executable, "-c", FLOOD_CHILD, pair.slave_path, payload.hex()],
                                 start_new_session=True)
        try:
            channel = DeviceChannel(pair)
            assert pair.read(65536, 5.0)           # the flood is on
            t0 = time.monotonic()
            with pytest.raises(DeviceTimeout, match="HELLO"):
                channel.expect(lambda f: isinstance(f.msg, m.Stats), 1.0, "HELLO")
            took = time.monotonic() - t0
        finally:
            child.kill()
            child.wait()
        assert 1.0 <= took < 2.0, took          # the flood would go on for 15 s
        if payload is UNRELATED:
            assert channel.skipped > 1000


@pytest.mark.parametrize("payload", [GARBAGE, UNRELATED], ids=["bytes", "valid-frames"])
def test_streamer_timeout_holds_while_peer_floods(payload: bytes) -> None:
    """A 'device' that answers no measurement but never goes quiet: the run fails within its timeout
    plus the STATS probe's bound (min(2, timeout))."""
    with PtyPair(PtyOptions(write_timeout_s=1.0)) as pair:
        slave = pair.slave_fd
        assert slave is not None

        flight = scenario_flight("hover", mode="twr", duration_s=3.0, seed=1, noise="none")
        with FloodPeer(slave, payload):
            t0 = time.monotonic()
            with pytest.raises(DeviceTimeout, match="silent|STATS"):
                Streamer(DeviceChannel(pair), timeout_s=1.0).run(flight, config_for(flight, EstimatorConfig()), Pacing("windowed", 8))
            took = time.monotonic() - t0
        assert took < 1.0 + 1.0 + 1.0, took


class TcpFlood:
    """A TCP 'board' (socket:// URL) that floods every client with `payload`."""

    def __init__(self, payload: bytes, max_s: float = 20.0) -> None:
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = self.srv.getsockname()[1]
        self.payload, self.max_s = payload, max_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)

    def __enter__(self) -> TcpFlood:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        self.srv.close()

    def _serve(self) -> None:
        self.srv.settimeout(0.2)
        end = time.monotonic() + self.max_s
        conn = None
        while conn is None and not self._stop.is_set() and time.monotonic() < end:
            try:
                conn, _ = self.srv.accept()
            except socket.timeout:
                continue
        if conn is None:
            return
        with conn:
            conn.setblocking(False)
            while not self._stop.is_set() and time.monotonic() < end:
                r, w, _ = select.select([conn], [conn], [], 0.05)
                try:
                    if r and not conn.recv(65536):
                        return
                    if w:
                        conn.send(self.payload)
                except (BlockingIOError, InterruptedError):
                    pass
                except OSError:
                    return


@pytest.mark.parametrize("payload", [GARBAGE, UNRELATED], ids=["bytes", "valid-frames"])
def test_cli_timeout_holds_while_board_floods(payload: bytes) -> None:
    with TcpFlood(payload) as board:
        t0 = time.monotonic()
        out = subprocess.run([*UWB_HIL, "run", "--port", f"socket://127.0.0.1:{board.port}", "--timeout", "2",
                              "--duration", "3"], capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)
        took = time.monotonic() - t0
    assert out.returncode != 0
    # the HELLO wait itself ends at the 2 s bound (the flood would go on for 20 s)
    assert re.search(r"uwb-hil: error: device did not answer HELLO within 2\.[0-4]\d s", out.stderr), out.stderr
    assert "Traceback" not in out.stderr
    assert took < 15.0, took               # + interpreter start-up and flight build, on a loaded machine


@pytest.mark.parametrize("payload", [GARBAGE, UNRELATED], ids=["bytes", "valid-frames"])
def test_streamer_setup_holds_its_timeout_while_peer_floods(payload: bytes) -> None:
    """The set-up barrier (CONFIG + ANCHOR + STATS_REQ) waits the streamer's timeout, not a fixed 5 s: over
    a link that injects faults the STATS probe before the run is skipped, so the barrier is the first wait."""
    with PtyPair(PtyOptions(write_timeout_s=1.0)) as pair:
        assert pair.slave_fd is not None
        pair.injects_faults = True     # type: ignore[attr-defined]
        flight = scenario_flight("hover", mode="twr", duration_s=3.0, seed=1, noise="none")
        with FloodPeer(pair.slave_fd, payload):
            t0 = time.monotonic()
            with pytest.raises(DeviceTimeout, match="CONFIG"):
                Streamer(DeviceChannel(pair), timeout_s=1.0).run(flight, config_for(flight, EstimatorConfig()),
                                                                  Pacing("windowed", 8))
            took = time.monotonic() - t0
        assert took < 1.0 + 1.0, took
