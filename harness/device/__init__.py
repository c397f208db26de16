"""Devices under test: the host emulator on a pty, a board on a serial port (QEMU: device/qemu.py)."""

from __future__ import annotations

from harness.device.base import Device
from harness.device.channel import DeviceChannel
from harness.device.identity import DeviceIdentity
from harness.device.emulator import EmulatorDevice, EmulatorOptions
from harness.device.serial_device import SerialDevice, SerialDeviceOptions

__all__ = ["Device", "DeviceChannel", "DeviceIdentity", "EmulatorDevice", "EmulatorOptions", "SerialDevice",
           "SerialDeviceOptions"]
