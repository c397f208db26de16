"""Several boards: a board list (YAML) or repeated --target/--port options -> `BoardSpec`s.

One board list serves `uwb-hil campaign --boards FILE` and the pytest plugin's `--uwb-hardware-map FILE`:

    - name: bench-1                # unique; defaults to target-N
      port: /dev/ttyACM0           # or rfc2217://host:port, socket://...
      target: serial               # host | asan | serial | qemu (default: serial with a port, else host)
      baud: 115200
    - name: bench-2
      serial_number: 0672FF3830   # the board with this USB serial number, wherever it is plugged in
    - name: sim
      target: qemu                 # a QEMU board (the STM32 ELF), started by the harness
      firmware: firmware_sim/build/stm32/uwb-fw.elf

A bad file is an input error naming the entry and the field (exit 2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from harness.device.registry import TARGETS, DeviceSpec, canonical_target
from harness.errors import InputError
from harness.options import DEFAULT_BAUD, DEVICE_TIMEOUT_S, MAX_BAUD

FIELDS = ("name", "port", "serial_number", "target", "baud", "firmware")


@dataclass(frozen=True)
class BoardSpec:
    """One board: what it is and how to reach it."""

    name: str
    target: str = "host"
    port: str | None = None
    serial_number: str | None = None     # USB serial number (resolved to a port when used)
    baud: int = DEFAULT_BAUD
    firmware: Path | None = None         # host binary / ELF of a board the harness starts; None: the default
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def resolved_port(self) -> str | None:
        """The port, or the device path of the USB serial number (PortError when absent)."""
        if self.port or not self.serial_number:
            return self.port
        from harness.link.ports import port_for_serial
        return port_for_serial(self.serial_number)

    def device_spec(self, timeout_s: float = DEVICE_TIMEOUT_S, log_dir: Path | None = None) -> DeviceSpec:
        return DeviceSpec(target=self.target, port=self.resolved_port(), baud=self.baud, firmware=self.firmware,
                          timeout_s=timeout_s, log_dir=log_dir)

    def fixture_values(self) -> tuple[str, str | None, int, str]:
        """(target, port, baud, firmware) for the pytest plugin's device fixtures."""
        from harness.device.registry import default_firmware
        fw = self.firmware if self.firmware is not None else default_firmware(self.target)
        return self.target, self.resolved_port(), self.baud, str(fw)

    def identity_text(self, hello: dict[str, Any]) -> str:
        """One line: the board and what its HELLO said (a JUnit property, a log line)."""
        where = self.resolved_port() or self.target
        serial = self.serial_number or (usb_serial_number(where) if self.port else None)
        return (f"{self.target} {where}" + (f" serial {serial}" if serial else "")
                + f" build {hello.get('build_id')} model {hello.get('model_hash')} firmware {hello.get('firmware')}")

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "target": self.target, "port": self.port, "baud": self.baud}
        if self.serial_number:
            d["serial_number"] = self.serial_number
        if self.firmware is not None:
            d["firmware"] = str(self.firmware)
        return d


def usb_serial_number(port: str) -> str | None:
    """The USB serial number of a local port, when it is a USB device (None otherwise)."""
    from harness.link.ports import is_local_device, list_ports
    if not port or not is_local_device(port):
        return None
    return next((p.serial_number for p in list_ports() if p.device == port), None)


def _entry(i: int, raw: Any, base: Path) -> BoardSpec:
    where = f"board list entry {i + 1}"
    if not isinstance(raw, dict):
        raise InputError(f"{where}: expected a mapping with {', '.join(FIELDS)}, got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(FIELDS))
    if unknown:
        raise InputError(f"{where}: unknown field(s) {unknown}; known: {', '.join(FIELDS)}")
    port = str(raw["port"]) if raw.get("port") else None
    serial = str(raw["serial_number"]) if raw.get("serial_number") else None
    if port and serial:
        raise InputError(f"{where}: give port or serial_number, not both")
    target = canonical_target(str(raw.get("target") or ("serial" if port or serial else "host")))
    if target not in TARGETS:
        raise InputError(f"{where}: unknown target {target!r}; choose one of {', '.join(TARGETS)}")
    if target == "serial" and not (port or serial):
        raise InputError(f"{where}: target serial needs a port or a serial_number")
    try:
        baud = int(raw.get("baud", DEFAULT_BAUD))
    except (TypeError, ValueError):
        raise InputError(f"{where}: baud must be an integer, got {raw.get('baud')!r}") from None
    if not 1 <= baud <= MAX_BAUD:         # as --baud (it was exit 3: "could not open port ... at -5 baud")
        raise InputError(f"{where}: baud must be >= 1 and <= {MAX_BAUD:g}, got {baud}")
    fw = raw.get("firmware")
    firmware = (base / str(fw)).resolve() if fw else None
    return BoardSpec(name=str(raw.get("name") or f"{target}-{i + 1}"), target=target, port=port,
                     serial_number=serial, baud=baud, firmware=firmware)


def load_board_list(path: Path) -> list[BoardSpec]:
    """The boards of a YAML board list (a list of mappings, or {"boards": [...]})."""
    import yaml
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"board list {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"board list {path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise InputError(f"board list {path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if isinstance(data, dict) and "boards" in data:
        data = data["boards"]
    if not isinstance(data, list) or not data:
        raise InputError(f"board list {path}: expected a non-empty list of boards")
    return check_unique([_entry(i, raw, Path(path).parent) for i, raw in enumerate(data)])


def boards_from_options(targets: list[str], ports: list[str], baud: int = DEFAULT_BAUD,
                        firmware: Path | None = None) -> list[BoardSpec]:
    """Boards from repeated --target / --port: one board per port (each with the --target of the same
    position, or the one --target given, default serial), or without ports one board per --target."""
    if ports:
        if len(targets) not in (0, 1, len(ports)):
            raise InputError(f"{len(targets)} --target for {len(ports)} --port: give one --target, or one per --port")
        kinds = targets * len(ports) if len(targets) == 1 else (targets or ["serial"] * len(ports))
        out = [BoardSpec(name=f"{canonical_target(t)}-{i + 1}", target=canonical_target(t), port=p, baud=baud,
                         firmware=firmware) for i, (t, p) in enumerate(zip(kinds, ports))]
    else:
        if "serial" in targets:
            raise InputError("--target serial needs --port (one per board)")
        out = [BoardSpec(name=f"{canonical_target(t)}-{i + 1}", target=canonical_target(t), firmware=firmware)
               for i, t in enumerate(targets)]
    for b in out:
        if b.target not in TARGETS:
            raise InputError(f"unknown target {b.target!r}; choose one of {', '.join(TARGETS)}")
    return check_unique(out)


def check_unique(boards: list[BoardSpec]) -> list[BoardSpec]:
    names = [b.name for b in boards]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"board names must be unique: {', '.join(dup)} given more than once")
    ports = [b.port for b in boards if b.port]
    dup = sorted({p for p in ports if ports.count(p) > 1})
    if dup:
        raise InputError(f"one port, one board: {', '.join(dup)} given more than once")
    return boards
