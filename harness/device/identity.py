"""`DeviceIdentity`: who the device is, read once from its HELLO_REPLY. Summaries, results headers, reports
and the pytest plugin's JUnit properties all take their fields from here (one conversion, not four)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from protocol.messages import HelloReply


def _ascii(raw: bytes) -> str:
    return raw.rstrip(b"\x00").decode("ascii", errors="replace")


@dataclass(frozen=True)
class DeviceIdentity:
    proto_version: int
    firmware: str             # "major.minor.patch"
    build_id: str
    target: str
    model_hash: int
    cost_unit: int
    layout_twr: int
    layout_tdoa: int
    reply: HelloReply         # the HELLO_REPLY itself (its raw fields)

    @classmethod
    def from_reply(cls, reply: HelloReply) -> DeviceIdentity:
        return cls(proto_version=reply.proto_version, firmware=f"{reply.fw_major}.{reply.fw_minor}.{reply.fw_patch}",
                   build_id=_ascii(reply.build_id), target=_ascii(reply.target), model_hash=reply.model_hash,
                   cost_unit=reply.cost_unit, layout_twr=reply.layout_twr, layout_tdoa=reply.layout_tdoa, reply=reply)

    @property
    def layouts(self) -> tuple[int, int]:
        """The (TWR, TDoA) bias network layouts."""
        return self.layout_twr, self.layout_tdoa

    def as_dict(self) -> dict[str, Any]:
        """The identity as run summaries, results headers and campaign summaries record it."""
        return {"proto_version": self.proto_version, "firmware": self.firmware, "build_id": self.build_id,
                "target": self.target, "model_hash": f"{self.model_hash:016x}", "layout_twr": self.layout_twr,
                "layout_tdoa": self.layout_tdoa, "cost_unit": self.cost_unit}

    def describe(self) -> dict[str, Any]:
        """The identity as `Device.describe()` reports it (the hash as the CLI prints it: 16 hex digits, no 0x)."""
        return self.as_dict()

    def properties(self) -> dict[str, str]:
        """JUnit test-suite properties (pytest plugin); the model hash in the CLI's form (no 0x)."""
        return {"uwb_fw_version": self.firmware, "uwb_build_id": self.build_id,
                "uwb_model_hash": f"{self.model_hash:016x}", "uwb_device_target": self.target,
                "uwb_proto_version": str(self.proto_version),
                "uwb_layouts": f"twr={self.layout_twr} tdoa={self.layout_tdoa}"}
