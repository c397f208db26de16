"""Device lifecycle with stand-in firmware: tiny scripts started the way uwb-fw is (`--tty <slave>`).

The protocol-speaking stand-in answers HELLO from Python (protocol.framing), so the handshake,
mismatch checks, death and silence are tested without the C firmware.
"""

from __future__ import annotations

import gc
import os
import socket
import stat
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from harness.device import Device, DeviceChannel, HostDevice, HostOptions, SerialDevice
from harness.errors import (DeviceDied, DeviceError, DeviceTimeout, LinkClosed, ModelMismatch, ProtocolMismatch,
                            UwbHilError)
from harness.link import open_link
from protocol import PROTOCOL_VERSION
from protocol.framing import FrameDecoder, encode_frame
from protocol.messages import Hello, HelloReply, StatsReq

pytestmark = pytest.mark.timeout(60)

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


def _script(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture
def fake_fw(tmp_path: Path) -> Path:
    return _script(tmp_path, "fake-fw", f"#!{sys.executable}\n{FAKE_FIRMWARE}")


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
    fw = _script(tmp_path, "dying-fw", "#!/bin/sh\necho 'fatal: estimator exploded' >&2\nsleep 0.5\nexit 3\n")
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
    fw = _script(tmp_path, "bad-fw", "#!/bin/sh\necho 'usage: bad-fw' >&2\nexit 2\n")
    dev = HostDevice(fw, log_dir=log_dir)
    with pytest.raises(DeviceDied, match="right after start") as info:
        dev.start()
    assert info.value.exit_code == 2 and "usage: bad-fw" in info.value.log_tail
    assert dev.stop() == 2  # already stopped by start(): idempotent


def test_device_killed_by_a_signal_reports_it(tmp_path: Path, log_dir: Path) -> None:
    fw = _script(tmp_path, "segv-fw", "#!/bin/sh\nsleep 0.4\nkill -SEGV $$\n")
    with HostDevice(fw, log_dir=log_dir) as dev:
        with pytest.raises(DeviceDied, match="SIGSEGV") as info:
            dev.hello(timeout=5)
        assert info.value.exit_code == -11


def test_silent_device_times_out_on_hello_within_the_timeout(tmp_path: Path, log_dir: Path) -> None:
    fw = _script(tmp_path, "silent-fw", "#!/bin/sh\nexec sleep 100\n")
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
    fw = _script(tmp_path, "stubborn-fw", "#!/bin/sh\ntrap '' TERM\nexec sleep 100\n")
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
    fw = _script(tmp_path, "forking-fw", f"#!/bin/sh\nsleep 100 &\necho $! > {pid_file}\nwait\n")
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
    fw = _script(tmp_path, "silent-fw", "#!/bin/sh\nexec sleep 100\n")
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
class FakeBoard:
    """A 'board' behind socket://: answers HELLO over TCP from a thread."""

    def __init__(self, stale: bytes = b"") -> None:
        self._srv = socket.create_server(("127.0.0.1", 0))
        self._srv.settimeout(5.0)
        self.url = f"socket://127.0.0.1:{self._srv.getsockname()[1]}"
        self._stale = stale
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            conn, _ = self._srv.accept()
        except OSError:
            return
        conn.settimeout(0.05)
        dec = FrameDecoder()
        with conn:
            if self._stale:
                conn.sendall(self._stale)
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                for f in dec.feed(data):
                    if isinstance(f.msg, Hello):
                        conn.sendall(encode_frame(HelloReply(f.msg.nonce, PROTOCOL_VERSION, 0, 9, 0, 1, 0, 0, 7,
                                                             b"board", b"stm32"), f.seq))

    def close(self) -> None:
        self._stop.set()
        self._srv.close()
        self._thread.join(5)


@pytest.fixture
def board() -> Iterator[FakeBoard]:
    b = FakeBoard(stale=b"boot log line\r\n" * 4)
    yield b
    b.close()


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


# ---------------------------------------------------------------------------- pytest plugin
pytest_plugins = ["pytester"]
# Inner runs re-import every plugin; hypothesis alone takes a second and is not needed there.
_LEAN = ("-p", "no:hypothesispytest", "-p", "no:cacheprovider")


def _run(pytester: pytest.Pytester, *args: str) -> pytest.RunResult:
    return pytester.runpytest(*_LEAN, *args)

OPTION_PROBE = """
import pytest

def test_values(uwb_port, uwb_baud, uwb_target, uwb_firmware, uwb_timeout):
    print("VALUES", uwb_port, uwb_baud, uwb_target, uwb_firmware.name, uwb_timeout)

@pytest.mark.parametrize("uwb_baud", [921600], indirect=True)
@pytest.mark.parametrize("uwb_port", ["socket://127.0.0.1:9"], indirect=True)
def test_indirect(uwb_port, uwb_baud, uwb_target):
    print("INDIRECT", uwb_port, uwb_baud, uwb_target)

@pytest.mark.hardware
def test_board_only():
    print("HARDWARE RAN")
"""


def test_plugin_is_inert_in_a_project_that_does_not_ask_for_it(pytester: pytest.Pytester) -> None:
    """Installed in an environment, the plugin loads in every pytest session: without a --uwb-* option or
    `uwb_hil = true` in the ini, no header, and a project's own `hardware` marker is left alone."""
    pytester.makeini("[pytest]\nmarkers =\n    hardware: this project's own marker\n")
    pytester.makepyfile("import pytest\n\n@pytest.mark.hardware\ndef test_mine():\n    pass\n")
    result = _run(pytester)
    result.assert_outcomes(passed=1)
    assert "uwb-hil:" not in result.stdout.str()          # (pytest itself lists "plugins: uwb-hil-...")
    asked = _run(pytester, "--uwb-timeout", "2")             # any --uwb-* option asks for it
    asked.assert_outcomes(skipped=1)
    asked.stdout.fnmatch_lines(["uwb-hil: target host, *"])


def test_plugin_options_are_in_their_own_help_group(pytester: pytest.Pytester) -> None:
    result = _run(pytester, "--help")
    result.stdout.fnmatch_lines(["*uwb-hil*", "*--uwb-port*", "*--uwb-baud*", "*--uwb-target*",
                                 "*--uwb-firmware*", "*--uwb-timeout*"])


def test_plugin_option_fixtures_defaults_cli_and_indirect(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(OPTION_PROBE)
    pytester.makeini("[pytest]\nuwb_hil = true\n")     # a project that asks for the plugin without options
    result = _run(pytester, "-s", "-rs")
    result.assert_outcomes(passed=2, skipped=1)
    result.stdout.fnmatch_lines(["*VALUES None 115200 host uwb-fw 5.0",
                                 "*INDIRECT socket://127.0.0.1:9 921600 serial",
                                 "*needs a real board*"])
    result = _run(pytester, "-s", "--uwb-port", "loop://", "--uwb-baud", "9600", "--uwb-timeout", "2",
                                "--uwb-firmware", "/x/fw")
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines(["*VALUES loop:// 9600 serial fw 2.0", "*HARDWARE RAN"])
    result = _run(pytester, "-s", "--uwb-target", "qemu", "-k", "values")      # qemu: the STM32 ELF by default
    result.stdout.fnmatch_lines(["*VALUES None 115200 qemu uwb-fw.elf 5.0"])


def test_plugin_uwb_device_records_hello(pytester: pytest.Pytester, fake_fw: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            assert uwb_device.alive()
            assert uwb_device.last_hello.fw_minor == 2
            print("DEVICE", uwb_device.link.name)
    """)
    xml = pytester.path / "junit.xml"
    result = _run(pytester, "-s", "--uwb-firmware", str(fake_fw), f"--junitxml={xml}")
    result.assert_outcomes(passed=1, warnings=0)
    result.stdout.fnmatch_lines(["uwb-hil: target host, firmware *fake-fw", "*DEVICE pty:/dev/*"])
    text = xml.read_text()
    for expected in ('name="uwb_fw_version" value="1.2.3"', 'name="uwb_build_id" value="fake-id"',
                     f'name="uwb_model_hash" value="{FAKE_HASH:016x}"', 'name="uwb_device_target" value="fake"',
                     'name="uwb_target" value="host"', 'name="uwb_port" value="/dev/'):
        assert expected in text
    # test-suite properties (xunit2 rejects them inside a testcase)
    assert text.index("<properties>") < text.index("<testcase") and "</properties></testcase>" not in text


def test_plugin_failing_test_shows_the_device_log(pytester: pytest.Pytester, fake_fw: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            assert False, "estimate diverged"
    """)
    result = _run(pytester, "--uwb-firmware", str(fake_fw))
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*uwb device log (tail)*", "*fake firmware serving /dev/pts/*"])


def test_plugin_uwb_device_checks_the_protocol_and_always_stops(pytester: pytest.Pytester, fake_fw: Path) -> None:
    wrapper = _script(pytester.path, "fw-proto-99", f"#!/bin/sh\nexec {fake_fw} \"$@\" --proto 99\n")
    pytester.makepyfile("""
        def test_dev(uwb_device):
            pass
    """)
    result = _run(pytester, "--uwb-firmware", str(wrapper))
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*ProtocolMismatch*reports 99*"])


def test_plugin_uwb_device_on_a_serial_url(pytester: pytest.Pytester, board: FakeBoard) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device, uwb_target):
            assert uwb_target == "serial"
            assert uwb_device.last_hello.target.rstrip(b"\\0") == b"stm32"
    """)
    result = _run(pytester, "--uwb-port", board.url)
    result.assert_outcomes(passed=1)


def test_plugin_missing_firmware_is_a_clear_error(pytester: pytest.Pytester, tmp_path: Path) -> None:
    pytester.makepyfile("""
        def test_dev(uwb_device):
            pass
    """)
    result = _run(pytester, "--uwb-firmware", str(tmp_path / "nope"))
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*firmware binary*nope not found*make firmware*"])

