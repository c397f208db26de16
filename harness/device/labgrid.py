"""A board from a labgrid farm (the [farm] extra: `pip install 'uwb-hil[farm]'`, labgrid from PyPI).

`place(PlaceOptions(name))` acquires the place from the labgrid coordinator (gRPC, labgrid >= 24:
`labgrid-client -x HOST:PORT -p NAME acquire`), reads its serial resource from the place's environment
(`labgrid-client env`: a NetworkSerialPort, which the exporter serves as RFC 2217 through ser2net), yields
the pyserial URL `rfc2217://host:port`, and releases the place at the end, also on an error, Ctrl-C or
SIGTERM. A place another user or host holds is refused by the coordinator: DeviceError (exit 3) with
labgrid's reason. labgrid is driven through its own client (`labgrid-client`), every call with a timeout.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from harness.errors import DeviceError, InputError
from harness.optional import MissingDependencyError
from harness.options import DEFAULT_BAUD

COORDINATOR_ENV = "LG_COORDINATOR"         # labgrid's own variable
DEFAULT_COORDINATOR = "127.0.0.1:20408"    # labgrid-coordinator's default
FARM_EXTRA_HINT = "pip install 'uwb-hil[farm]' (from a checkout: pip install -e '.[farm]'; `make` installs it)"


@dataclass(frozen=True)
class PlaceOptions:
    name: str
    coordinator: str | None = None     # HOST:PORT; default $LG_COORDINATOR, else 127.0.0.1:20408
    timeout_s: float = 30.0            # of each labgrid-client call

    def address(self) -> str:
        return self.coordinator or os.environ.get(COORDINATOR_ENV) or DEFAULT_COORDINATOR


@dataclass(frozen=True)
class Lease:
    """An acquired place and its serial port."""

    place: str
    coordinator: str
    url: str                     # rfc2217://host:port
    resource: dict[str, Any]     # the NetworkSerialPort's parameters (host, port, speed)

    @property
    def baud(self) -> int:
        return int(self.resource.get("speed") or DEFAULT_BAUD)


def client_binary() -> str:
    """labgrid-client: next to this interpreter (a virtualenv), else on PATH."""
    here = Path(sys.executable).parent / "labgrid-client"
    found = str(here) if here.exists() else shutil.which("labgrid-client")
    if found is None:
        raise MissingDependencyError(f"--labgrid-place needs labgrid, which is not installed: {FARM_EXTRA_HINT}")
    return found


def _client(opts: PlaceOptions, *args: str) -> str:
    cmd = [client_binary(), "-x", opts.address(), "-p", opts.name, *args]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=opts.timeout_s, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        raise DeviceError(f"labgrid place {opts.name}: `labgrid-client {' '.join(args)}` did not answer within "
                          f"{opts.timeout_s:g} s (coordinator {opts.address()})") from None
    if out.returncode != 0:
        lines = [ln for ln in (out.stderr or out.stdout).strip().splitlines() if ln.strip()]
        reason = lines[-1] if lines else f"exit code {out.returncode}"
        raise DeviceError(f"labgrid place {opts.name}: {' '.join(args)} refused: {reason.removeprefix('labgrid-client: ')}")
    return out.stdout


def serial_resource(env_yaml: str, place: str) -> dict[str, Any]:
    """The NetworkSerialPort of a place's environment (`labgrid-client env`)."""
    import yaml
    try:
        env = yaml.safe_load(env_yaml) or {}
        resources = env["targets"][place]["resources"]
    except (yaml.YAMLError, KeyError, TypeError):
        raise DeviceError(f"labgrid place {place}: its environment lists no resources") from None
    for item in resources if isinstance(resources, list) else [resources]:
        if isinstance(item, dict) and isinstance(item.get("NetworkSerialPort"), dict):
            res = dict(item["NetworkSerialPort"])
            if res.get("host") and res.get("port"):
                return res
    raise DeviceError(f"labgrid place {place}: no NetworkSerialPort among its resources (an exporter's "
                      "RawSerialPort or USBSerialPort is exported as one)")


@contextmanager
def _released_on_sigterm() -> Iterator[None]:
    """SIGTERM unwinds like Ctrl-C (so the place is released); only where Python can take signals."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: FrameType | None) -> None:  # noqa: ARG001
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def place(opts: PlaceOptions) -> Iterator[Lease]:
    """Acquire the place, yield its serial port, always release it."""
    if not opts.name:
        raise InputError("--labgrid-place needs a place name")
    with _released_on_sigterm():
        try:
            _client(opts, "acquire")
        except (KeyboardInterrupt, SystemExit):     # interrupted while the coordinator may have granted it
            release(opts)
            raise
        try:
            res = serial_resource(_client(opts, "env"), opts.name)
            yield Lease(place=opts.name, coordinator=opts.address(), url=f"rfc2217://{res['host']}:{res['port']}",
                        resource=res)
        finally:
            release(opts)


def release(opts: PlaceOptions) -> None:
    """Release the place (a failure to release is reported on stderr, never hides the run's own outcome)."""
    try:
        _client(opts, "release")
    except DeviceError as exc:
        print(f"uwb-hil: warning: {exc}", file=sys.stderr)
