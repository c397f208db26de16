"""`HostDevice`: the host build of the firmware (`uwb-fw --tty <pty slave>`) as a child process.

Lifecycle:
  start  raw pty pair -> Popen([*wrapper, binary, "--tty", slave, *args]) in its own session
         (Ctrl-C in the terminal reaches pytest, not the firmware), stdin /dev/null, stdout and
         stderr to a per-device log file; the child inherits the slave fd, so the harness drops
         its own copy and the child's exit shows up at once as EIO on the master; then a short
         check that it did not exit immediately;
  stop   SIGTERM to the process group -> wait -> SIGKILL -> wait; stragglers of the group (a
         wrapper's children) are killed while the leader is still unreaped, so the group id cannot
         have been reused. Idempotent; a weakref finalizer does the same if the object is dropped
         or the interpreter exits with the device running.
The exit status is observed without reaping (waitid WNOWAIT) until stop() reaps it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from harness.device.base import Device
from harness.device.process_log import exit_error, new_log_path, remove_tmp_dir
from harness.errors import DeviceDied, DeviceError
from harness.link.base import Link
from harness.link.pty_link import PtyOptions, PtyPair

_POLL_S = 0.005


@dataclass(frozen=True)
class HostOptions:
    startup_check_s: float = 0.1     # the process must survive this long after exec
    stop_timeout_s: float = 1.0      # per stage: after SIGTERM, after SIGKILL
    write_timeout_s: float = 5.0     # link writes fail after this long without progress
    death_grace_s: float = 0.5       # on a closed link, wait this long for the exit to be visible
    log_tail_lines: int = 30


class HostDevice(Device):
    """The host firmware binary serving a raw pty."""

    def __init__(self, binary: Path | str, args: Sequence[str] = (), log_dir: Path | str | None = None,
                 env: Mapping[str, str] | None = None, wrapper: Sequence[str] | None = None,
                 options: HostOptions = HostOptions()) -> None:
        super().__init__()
        self.binary = Path(binary)
        self.args = tuple(args)
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.env = dict(env) if env is not None else None       # added to (overrides) os.environ
        self.wrapper = tuple(wrapper) if wrapper else ()        # e.g. ("valgrind", "--error-exitcode=99")
        self.options = options
        self.log_path: Path | None = None
        self.returncode: int | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._pty: PtyPair | None = None
        self._tmp_log_dir: str | None = None
        self._finalizer: weakref.finalize[..., HostDevice] | None = None

    # ------------------------------------------------------------------------------- identity
    @property
    def name(self) -> str:
        pid = f" pid {self._proc.pid}" if self._proc is not None else ""
        return f"host {self.binary.name}{pid}"

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    @property
    def link(self) -> Link:
        return self._running(self._pty)

    @property
    def death_grace_s(self) -> float:  # type: ignore[override]
        return self.options.death_grace_s

    def command(self, tty_path: str) -> list[str]:
        return [*self.wrapper, str(self.binary), "--tty", tty_path, *self.args]

    # ------------------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._not_running(self._proc)
        if not self.binary.is_file():
            raise DeviceError(f"firmware binary {self.binary} not found (build it: `make firmware`)")
        if not os.access(self.binary, os.X_OK):
            raise DeviceError(f"firmware binary {self.binary} is not executable")
        self.returncode = None
        pty = PtyPair(PtyOptions(write_timeout_s=self.options.write_timeout_s))
        cmd = self.command(pty.slave_path)
        env = {**os.environ, **self.env} if self.env is not None else None
        slave = pty.slave_fd
        assert slave is not None  # a fresh pair holds its slave
        try:
            self.log_path = self._new_log_path()
            with open(self.log_path, "wb") as log:
                log.write(("$ " + " ".join(cmd) + "\n").encode())
                log.flush()
                self._proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                              env=env, pass_fds=(slave,), start_new_session=True)
        except OSError as exc:
            pty.close()
            self._remove_tmp_log()
            raise DeviceError(f"cannot start `{' '.join(cmd)}`: {exc}") from exc
        pty.release_slave()
        self._pty = pty
        self._finalizer = weakref.finalize(self, _reap, self._proc, pty, self.options.stop_timeout_s,
                                           self._tmp_log_dir)
        dead = self.died(self.options.startup_check_s)
        if dead is not None:
            self.stop()
            raise DeviceDied(f"{self.binary.name} exited right after start", exit_code=dead.exit_code,
                             log_tail=dead.log_tail, log_path=dead.log_path)

    def alive(self) -> bool:
        return self._proc is not None and _exit_status(self._proc) is None

    def died(self, grace_s: float = 0.0) -> DeviceDied | None:
        proc = self._proc
        if proc is None:
            return None
        status = _wait_exit(proc, grace_s)
        if status is None:
            return None
        return exit_error(self.name, status, self.log_tail(), self.log_path, self._tmp_log_dir is None)

    def stop(self) -> int | None:
        proc, self._proc = self._proc, None
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None
        if proc is not None:
            self.returncode = _terminate(proc, self.options.stop_timeout_s)
        pty, self._pty = self._pty, None
        if pty is not None:
            pty.close()
        self._remove_tmp_log()
        return self.returncode

    def _remove_tmp_log(self) -> None:
        tmp, self._tmp_log_dir = self._tmp_log_dir, None
        if remove_tmp_dir(tmp):
            self.log_path = None

    # ------------------------------------------------------------------------------------ log
    def log_tail(self, lines: int | None = None) -> str:
        """The last lines of the device's stdout/stderr log."""
        if self.log_path is None:
            return ""
        n = self.options.log_tail_lines if lines is None else lines
        try:
            with open(self.log_path, "rb") as fh:
                fh.seek(0, os.SEEK_END)
                size = fh.tell()
                fh.seek(max(0, size - 200 * n))
                text = fh.read().decode("utf-8", errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-n:])

    def _new_log_path(self) -> Path:
        path, self._tmp_log_dir = new_log_path(self.log_dir, "uwb-fw-", self.binary.name)
        return path


# ------------------------------------------------------------------------- process helpers
def _exit_status(proc: subprocess.Popen[bytes]) -> int | None:
    """Exit code (negative: signal) if the process has exited, without reaping it."""
    if proc.returncode is not None:
        return proc.returncode
    try:
        info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:  # reaped by someone else's Popen.poll()
        return proc.poll()
    if info is None:
        return None
    return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status


def _wait_exit(proc: subprocess.Popen[bytes], timeout: float) -> int | None:
    deadline = time.monotonic() + max(0.0, timeout)
    while True:
        status = _exit_status(proc)
        if status is not None or time.monotonic() >= deadline:
            return status
        time.sleep(_POLL_S)


def _signal_group(proc: subprocess.Popen[bytes], sig: signal.Signals) -> None:
    """Signal the child's process group; only while the leader is unreaped (its pid = the pgid)."""
    if proc.returncode is not None:
        return
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            pass


def _terminate(proc: subprocess.Popen[bytes], timeout: float) -> int | None:
    """SIGTERM -> wait -> SIGKILL -> wait; kill the rest of the group; reap. Bounded in time."""
    if _exit_status(proc) is None:
        _signal_group(proc, signal.SIGTERM)
        if _wait_exit(proc, timeout) is None:
            _signal_group(proc, signal.SIGKILL)
            _wait_exit(proc, timeout)
    _signal_group(proc, signal.SIGKILL)  # stragglers; the unreaped leader keeps the group id ours
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:  # stuck in the kernel (D state): give up, do not hang
        return None


def _reap(proc: subprocess.Popen[bytes], pty: PtyPair, timeout: float, tmp_log_dir: str | None) -> None:
    """weakref finalizer: the device object is gone (or the interpreter exits) while running."""
    try:
        _terminate(proc, timeout)
    finally:
        pty.close()
        remove_tmp_dir(tmp_log_dir)
