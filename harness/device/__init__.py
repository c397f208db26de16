"""Devices under test: the registry (registry.py: DeviceSpec -> device), the one protocol session
(channel.py: DeviceChannel), and the devices: the host emulator on a pty, a board on a serial port, QEMU.

The names below load on first use: the pytest plugin imports harness.device.registry in every pytest run,
which must not pull numpy and the device classes in with this package."""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {"Device": "base", "DeviceChannel": "channel", "DeviceIdentity": "identity", "HostDevice": "host",
          "HostOptions": "host", "SerialDevice": "serial_device", "SerialDeviceOptions": "serial_device"}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'harness.device' has no attribute {name!r}")
    return getattr(importlib.import_module(f"harness.device.{_WHERE[name]}"), name)
