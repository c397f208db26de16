"""Device lifecycle with stand-in firmware: tiny scripts started the way uwb-fw is (`--tty <slave>`).

The protocol-speaking stand-in (stand_ins.py) answers HELLO from Python (protocol.framing), so the handshake,
mismatch checks, death and silence are tested without the C firmware; a serial board is a socket:// stand-in.
The pytest plugin's tests are in test_pytest_plugin.py.
"""

from __future__ import annotations

import gc
import time
from pathlib import Path

import pytest

from harness.device import Device, DeviceChannel, HostDevice, HostOptions, SerialDevice
from harness.errors import (DeviceDied, DeviceError, DeviceTimeout, LinkClosed, ModelMismatch, ProtocolMismatch,
                            UwbHilError)
from harness.link import open_link
from protocol import PROTOCOL_VERSION
from protocol.messages import Hello, HelloReply, StatsReq
from stand_ins import FAKE_HASH, FakeBoard, board, fake_fw, write_script  # noqa: F401

pytestmark = pytest.mark.timeout(60)

@pytest.fixture
def log_dir(tmp_path: Path) -> Path:
    return tmp_path / "logs"


def _gone(pid: int) -> bool:
    """Not running: no such process, or a zombie nobody has reaped yet (its parent was killed)."""
    try:
        stat_line = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True
    return stat_line.rsplit(")", 1)[1].split()[0] in ("Z", "X")


# ------------------------------------------------------------------------------ handshake
def test_hello_and_check_against_a_protocol_speaking_stand_in(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, log_dir=log_dir) as dev:
        assert dev.alive()
        reply = dev.hello(timeout=5)
        assert isinstance(reply, HelloReply)
        assert reply.proto_version == PROTOCOL_VERSION
        assert (reply.fw_major, reply.fw_minor, reply.fw_patch) == (1, 2, 3)
        assert dev.check(expected_model_hash=FAKE_HASH) is reply
        assert dev.check(expected_model_hash=f"{FAKE_HASH:x}", expected_layouts=(1, 2)) is reply
        desc = dev.describe()
        assert desc["model_hash"] == f"{FAKE_HASH:016x}" and desc["build_id"] == "fake-id"
        assert desc["link"]["kind"] == "pty"
        assert dev.link.name.startswith("pty:/dev/")
        log = dev.log_path
        assert log is not None and log.parent == log_dir
    assert dev.returncode == 0 or dev.returncode == -15
    assert "fake firmware serving" in log.read_text()
    assert not dev.alive()


def test_hello_skips_noise_and_replies_with_a_wrong_nonce(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, args=["--noise"], log_dir=log_dir) as dev:
        reply = dev.hello(timeout=5)
        assert reply.build_id.rstrip(b"\0") == b"fake-id"
        assert dev.channel.skipped == 1
        assert dev.channel.errors.total() >= 1


def test_hello_is_repeated_while_the_device_does_not_answer(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, args=["--ignore-first"], log_dir=log_dir) as dev:
        dev.hello_resend_s = 0.2
        reply = dev.hello(timeout=3)
        assert reply.proto_version == PROTOCOL_VERSION
        assert dev.channel.next_seq == 2  # two HELLOs went out


def test_protocol_mismatch_names_both_versions(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, args=["--proto", "99"], log_dir=log_dir) as dev:
        with pytest.raises(ProtocolMismatch, match=f"version {PROTOCOL_VERSION}.*reports 99") as info:
            dev.check()
        assert (info.value.expected, info.value.actual) == (PROTOCOL_VERSION, 99)


def test_model_mismatch_shows_hashes_in_hex_and_layouts(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, log_dir=log_dir, env={"FAKE_MODEL_HASH": "deadbeef"}) as dev:
        dev.hello(timeout=5)
        with pytest.raises(ModelMismatch) as info:
            dev.check(expected_model_hash=FAKE_HASH)
        text = str(info.value)
        assert "0x0123456789abcdef" in text and "0x00000000deadbeef" in text
        assert "TWR_POSE" in text and "TDOA_POSE" in text
        assert info.value.actual_hash == 0xDEADBEEF
        with pytest.raises(ModelMismatch, match="layouts"):
            dev.check(expected_layouts=(3, 4))
        dev.check()  # no expectation: fine


def test_wrapper_runs_the_binary_under_another_program(fake_fw: Path, log_dir: Path) -> None:
    dev = HostDevice(fake_fw, log_dir=log_dir, wrapper=["env", "FAKE_MODEL_HASH=42"])
    assert dev.command("/dev/pts/9")[:3] == ["env", "FAKE_MODEL_HASH=42", str(fake_fw)]
    with dev:
        assert dev.hello(timeout=5).model_hash == 0x42


# --------------------------------------------------------------------------------- failures
def test_device_that_exits_raises_device_died_with_exit_code_and_log(tmp_path: Path, log_dir: Path) -> None:
    fw = write_script(tmp_path, "dying-fw", "#!/bin/sh\necho 'fatal: estimator exploded' >&2\nsleep 0.5\nexit 3\n")
    dev = HostDevice(fw, log_dir=log_dir)
    dev.start()
    try:
        start = time.monotonic()
        with pytest.raises(DeviceDied) as info:
            dev.hello(timeout=10)
        assert time.monotonic() - start < 2.0
        assert info.value.exit_code == 3
        assert "estimator exploded" in info.value.log_tail
        assert "exit code 3" in str(info.value) and "estimator exploded" in str(info.value)
        assert not dev.alive()
    finally:
        assert dev.stop() == 3


def test_device_that_dies_mid_session_is_device_died(fake_fw: Path, log_dir: Path) -> None:
    with HostDevice(fake_fw, args=["--exit-after-hello", "5"], log_dir=log_dir) as dev:
        dev.hello(timeout=5)
        start = time.monotonic()
        with pytest.raises(DeviceDied) as info:
            dev.channel.recv(timeout=10)
        assert time.monotonic() - start < 2.0
        assert info.value.exit_code == 5
        assert "exiting on purpose" in info.value.log_tail
        with pytest.raises(DeviceDied):  # and sending to it says so too
            dev.channel.send(StatsReq())
            dev.channel.recv(timeout=10)


def test_device_that_exits_immediately_fails_start(tmp_path: Path, log_dir: Path) -> None:
    fw = write_script(tmp_path, "bad-fw", "#!/bin/sh\necho 'usage: bad-fw' >&2\nexit 2\n")
    dev = HostDevice(fw, log_dir=log_dir)
    with pytest.raises(DeviceDied, match="right after start") as info:
        dev.start()
    assert info.value.exit_code == 2 and "usage: bad-fw" in info.value.log_tail
    assert dev.stop() == 2  # already stopped by start(): idempotent


def test_device_killed_by_a_signal_reports_it(tmp_path: Path, log_dir: Path) -> None:
    fw = write_script(tmp_path, "segv-fw", "#!/bin/sh\nsleep 0.4\nkill -SEGV $$\n")
    with HostDevice(fw, log_dir=log_dir) as dev:
        with pytest.raises(DeviceDied, match="SIGSEGV") as info:
            dev.hello(timeout=5)
        assert info.value.exit_code == -11


def test_silent_device_times_out_on_hello_within_the_timeout(tmp_path: Path, log_dir: Path) -> None:
    fw = write_script(tmp_path, "silent-fw", "#!/bin/sh\nexec sleep 100\n")
    with HostDevice(fw, log_dir=log_dir) as dev:
        start = time.monotonic()
        with pytest.raises(DeviceTimeout) as info:
            dev.hello(timeout=0.6)
        elapsed = time.monotonic() - start
        assert 0.55 <= elapsed < 1.5
        assert info.value.request == "HELLO"
        assert "HELLO" in str(info.value) and "0.6" in str(info.value)
        assert dev.alive()


def test_stop_kills_a_device_that_ignores_sigterm(tmp_path: Path, log_dir: Path) -> None:
    fw = write_script(tmp_path, "stubborn-fw", "#!/bin/sh\ntrap '' TERM\nexec sleep 100\n")
    dev = HostDevice(fw, log_dir=log_dir, options=HostOptions(stop_timeout_s=0.5))
    dev.start()
    pid = dev.pid
    assert pid is not None
    start = time.monotonic()
    code = dev.stop()
    assert time.monotonic() - start < 2.0
    assert code == -9
    assert _gone(pid)
    assert dev.stop() == -9  # idempotent


def test_stop_also_kills_children_of_a_wrapper(tmp_path: Path, log_dir: Path) -> None:
    pid_file = tmp_path / "child.pid"
    fw = write_script(tmp_path, "forking-fw", f"#!/bin/sh\nsleep 100 &\necho $! > {pid_file}\nwait\n")
    dev = HostDevice(fw, log_dir=log_dir)
    dev.start()
    deadline = time.monotonic() + 5
    while not pid_file.exists() or not pid_file.read_text().strip():
        assert time.monotonic() < deadline
        time.sleep(0.01)
    child = int(pid_file.read_text())
    dev.stop()
    deadline = time.monotonic() + 2
    while not _gone(child) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _gone(child)


def test_a_dropped_device_is_reaped_by_its_finalizer(tmp_path: Path) -> None:
    fw = write_script(tmp_path, "silent-fw", "#!/bin/sh\nexec sleep 100\n")
    dev = HostDevice(fw)  # no log_dir: a temporary log, removed on stop
    dev.start()
    pid = dev.pid
    assert pid is not None and dev.log_path is not None and dev.log_path.exists()
    log = dev.log_path
    del dev
    gc.collect()
    assert _gone(pid)
    assert not log.exists()  # its temporary log went with it


def test_temporary_log_is_removed_by_stop(fake_fw: Path) -> None:
    with HostDevice(fake_fw) as dev:
        log = dev.log_path
        assert log is not None and log.exists()
    assert not log.exists() and dev.log_path is None


def test_missing_binary_and_unstarted_device_are_device_errors(tmp_path: Path) -> None:
    dev = HostDevice(tmp_path / "nope")
    with pytest.raises(DeviceError, match="not found"):
        dev.start()
    with pytest.raises(DeviceError, match="not started"):
        dev.link  # noqa: B018
    assert dev.stop() is None
    assert issubclass(DeviceError, UwbHilError)


def test_link_closed_without_a_dead_process_stays_link_closed(fake_fw: Path) -> None:
    class Closed:
        name = "closed"

        def write(self, data: bytes) -> None:
            raise LinkClosed("gone")

        def read(self, max_bytes: int, timeout: float) -> bytes:
            raise LinkClosed("gone")

    channel = DeviceChannel(Closed())  # type: ignore[arg-type]
    with pytest.raises(LinkClosed):
        channel.recv(0.1)
    with pytest.raises(LinkClosed):
        channel.send(Hello(nonce=1))


# ------------------------------------------------------------------------------ serial board
def test_serial_device_over_socket_url(board: FakeBoard) -> None:
    dev = SerialDevice(board.url, 115200)
    with dev:
        assert dev.alive()
        reply = dev.hello(timeout=5)
        assert reply.target.rstrip(b"\0") == b"stm32"
        assert dev.check().fw_minor == 9
        # the boot chatter is dropped at start, or (if it arrived late) it costs one HELLO resend
        assert dev.discarded_bytes in (0, len(b"boot log line\r\n" * 4))
        assert dev.describe()["link"]["url"] == board.url
    assert not dev.alive()
    assert dev.died() is None


def test_discard_input_drops_stale_bytes_until_quiet() -> None:
    with open_link("loop://") as link:
        link.write(b"stale" * 20)
        start = time.monotonic()
        assert link.discard_input(quiet_s=0.05, max_s=1.0) == 100
        assert time.monotonic() - start < 0.5
        assert link.read(10, 0.0) == b""


def test_silent_board_is_a_timeout_not_a_death() -> None:
    dev = SerialDevice("loop://")  # a loop echoes our HELLO back: not a reply
    with dev:
        with pytest.raises(DeviceTimeout):
            dev.hello(timeout=0.3)
        assert dev.channel.skipped >= 1


def test_device_is_abstract() -> None:
    with pytest.raises(TypeError):
        Device()  # type: ignore[abstract]
