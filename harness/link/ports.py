"""Serial ports of this machine (pyserial's list_ports): listing, the default port, picking by USB serial.

As pytest-embedded and twister's hardware map do, a board can be named by its USB serial number instead of
a device path that changes with the plug order (`--port-serial` / `--uwb-port-serial`), and the default
port comes from the environment (`UWB_HIL_PORT`), so one bench configuration serves every command.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from harness.errors import UwbHilError

ENV_PORT = "UWB_HIL_PORT"


class PortError(UwbHilError):
    """No port (or more than one) matches what was asked for; the message lists the ports present."""


@dataclass(frozen=True)
class PortInfo:
    device: str
    description: str
    serial_number: str | None
    hwid: str

    def as_dict(self) -> dict[str, str | None]:
        return {"device": self.device, "description": self.description, "serial_number": self.serial_number,
                "hwid": self.hwid}


def list_ports() -> list[PortInfo]:
    from serial.tools import list_ports as lp
    return sorted((PortInfo(device=p.device, description=p.description or "", serial_number=p.serial_number,
                            hwid=p.hwid or "") for p in lp.comports()), key=lambda p: p.device)


def ports_present(ports: list[PortInfo] | None = None) -> str:
    """One line for error messages: the ports present, with description and serial number."""
    ports = list_ports() if ports is None else ports
    if not ports:
        return "no serial ports found on this machine"
    return "ports present: " + "; ".join(
        f"{p.device} ({p.description}{f', serial {p.serial_number}' if p.serial_number else ''})" for p in ports)


def port_for_serial(serial_number: str, ports: list[PortInfo] | None = None) -> str:
    """The device path of the one port whose USB serial number is `serial_number`."""
    ports = list_ports() if ports is None else ports
    hits = [p for p in ports if p.serial_number == serial_number]
    if len(hits) != 1:
        what = "no serial port has" if not hits else f"{len(hits)} serial ports have"
        raise PortError(f"{what} USB serial number {serial_number!r}; {ports_present(ports)}")
    return hits[0].device


def default_port() -> str | None:
    """$UWB_HIL_PORT, if set and not empty."""
    return os.environ.get(ENV_PORT) or None


def is_local_device(url: str) -> bool:
    """A device path (not a pyserial URL such as rfc2217:// or socket://)."""
    return "://" not in url


def serial_number_of(url: str, ports: list[PortInfo] | None = None) -> str | None:
    """The USB serial number of a local port (by its resolved device path), None for a URL or a port without one."""
    if not is_local_device(url):
        return None
    try:
        ports = list_ports() if ports is None else ports
    except Exception:  # noqa: BLE001 - listing ports is best effort: the run does not depend on it
        return None
    want = os.path.realpath(url)
    return next((p.serial_number for p in ports if os.path.realpath(p.device) == want and p.serial_number), None)
