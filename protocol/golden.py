"""Golden test vectors: frames with their decoded meaning, shared by the Python and C tests.

    python -m protocol.golden            # rewrite protocol/golden/vectors.txt
    python -m protocol.golden --check    # exit 1 if the file differs from what the codec produces

Line format (one vector per line, '#' comments):
    <vector name> <seq> <frame hex incl. 0x00 delimiter> <MESSAGE NAME> <field>=<value> ...
Values: integers in decimal, floats as f:<IEEE-754 bits, 8 hex digits>, bytes as x:<hex>. Both test
suites decode the frame, compare every field, re-encode and compare the bytes.
"""

from __future__ import annotations

import argparse
import struct
import sys
from pathlib import Path
from typing import Any

from protocol import messages as m
from protocol.framing import encode_frame
from protocol.spec import load_spec

VECTORS_PATH = Path(__file__).with_name("golden") / "vectors.txt"
NAN = float("nan")


# A TDoA2 packet from anchor 3 (rangePacket2: type, seq[8], u32 timestamps[8], u16 distances[8]) with the
# LPP anchor position appended, and a TDoA3 packet from anchor 5 (header, one full and one short remote
# entry, LPP): the byte layouts of ../shared/reference/crazyflie-estimator-and-lps.md 4.4, 4.5, 4.7.
_LPP = bytes([0xF0, 0x01]) + struct.pack("<3f", 1.5, -2.25, 0.125)
_TDOA2_LPP = (bytes([0x22]) + bytes([1, 2, 3, 0x7F, 0, 5, 6, 7])
              + struct.pack("<8I", 10, 0, 0xFFFFFFFF, 0x80000000, 4, 5, 6, 7)
              + struct.pack("<8H", 33000, 0, 34000, 0, 65535, 1, 2, 3) + _LPP)
_TDOA3 = (bytes([0x30, 0x45]) + struct.pack("<I", 0xDEADBEEF) + bytes([2])
          + bytes([1, 0x80 | 0x11]) + struct.pack("<IH", 0x01020304, 33100)
          + bytes([9, 0x7F]) + struct.pack("<I", 0) + _LPP)


def _radio(t_us: int, rx_ts: int, src: int, payload: bytes) -> Any:
    return m.Radio(t_us=t_us, rx_ts=rx_ts, src_addr=src, length=len(payload), payload=payload.ljust(128, b"\0"))


def _vectors() -> list[tuple[str, int, Any]]:
    """Representative messages: every type, zero bytes (COBS), extremes, negative and special floats."""
    return _setup_and_sensor_vectors() + _reply_vectors() + _radio_and_control_vectors()


def _setup_and_sensor_vectors() -> list[tuple[str, int, Any]]:
    """Host to device: HELLO, CONFIG, ANCHOR and the measurements."""
    return [
        ("hello", 0, m.Hello(nonce=0xDEADBEEF)),
        ("hello_zero", 1, m.Hello(nonce=0)),
        # through the generated configuration: a CONFIG field added to messages.toml needs no edit here
        ("config_defaults", 2, m.EstimatorConfigBase(init_x=1.5).to_message(reset=1)),
        ("config_uwb_only", 3, m.EstimatorConfigBase(
            mode=1, stages=0, tdoa_match=2, std_twr=0.1, std_tdoa=0.3, a_max_twr=1.0, a_max_tdoa=2.0, gate_dt_min=0.005,
            chi2_twr=2.25, chi2_tdoa=3.24, proc_acc_xy=0.0, proc_acc_z=0.0, proc_cv_acc=1.0, init_x=-3.5,
            init_y=4.0, init_z=0.25, init_std_xy=100.0, init_std_z=1.0, nn_min_z=-1.0, sup_margin=0.0,
            sup_max_speed=1e6, sup_max_var=0.25, floor_imu=1).to_message(reset=0)),
        ("anchor0", 4, m.Anchor(anchor_id=0, x=-3.5, y=-4.0, z=0.0)),
        ("anchor15", 5, m.Anchor(anchor_id=15, x=3.1479, y=3.5671, z=0.16637)),
        ("imu_rest", 6, m.Imu(t_us=1000, ax=0.0, ay=0.0, az=9.81, gx=0.0, gy=0.0, gz=0.0)),
        ("imu_moving", 7, m.Imu(t_us=123456789012, ax=-0.125, ay=1e-3, az=9.5, gx=0.5, gy=-1.25, gz=3.0)),
        ("twr", 8, m.Twr(t_us=5000, anchor_id=3, range=4.2)),
        ("twr_seq_wrap", 0xFFFF, m.Twr(t_us=2**64 - 1, anchor_id=255, range=-0.0)),
        ("twr_nan", 9, m.Twr(t_us=5005, anchor_id=1, range=NAN)),
        ("tdoa", 10, m.Tdoa(t_us=7777, anchor_a=7, anchor_b=0, diff=-1.0625)),
        ("tdoa_inf", 11, m.Tdoa(t_us=7778, anchor_a=0, anchor_b=1, diff=float("inf"))),
        ("stats_req", 12, m.StatsReq()),
        ("height", 17, m.Height(t_us=5000, z=1.375, std=0.05)),
    ]


def _reply_vectors() -> list[tuple[str, int, Any]]:
    """Device to host: HELLO_REPLY, RESULT, STATS, ERROR."""
    return [
        ("hello_reply", 0, m.HelloReply(nonce=0xDEADBEEF, proto_version=1, fw_major=0, fw_minor=1, fw_patch=0,
                                        cost_unit=0, layout_twr=1, layout_tdoa=2,
                                        model_hash=0x0123456789ABCDEF, build_id=b"abc1234\x00",
                                        target=b"host\x00\x00\x00\x00")),
        ("result", 1, m.Result(meas_seq=8, kind=1, status=0, t_us=5000, innovation=0.03125, innovation_var=0.0625,
                               bias=-0.1, d_max=0.3, gain_x=0.25, gain_y=-0.5, gain_z=0.0, compute=1234,
                               cost_nn=600, cost_gates=20, cost_update=400, cost_predict=0, px=1.0, py=-2.0,
                               pz=1.5, vx=0.375, vy=0.0, vz=-0.01, qw=1.0, qx=0.0, qy=0.0, qz=0.0,
                               var_x=1e-3, var_y=1e-3, var_z=2e-3, var_vx=1e-2, var_vy=1e-2, var_vz=1e-2,
                               var_d0=1e-4, var_d1=1e-4, var_d2=1e-4, flags=0)),
        ("result_rejected", 2, m.Result(meas_seq=9, kind=2, status=2, t_us=7777, innovation=1.5,
                                        innovation_var=0.05, bias=0.0, d_max=0.1, gain_x=0.0, gain_y=0.0,
                                        gain_z=0.0, compute=999, cost_nn=0, cost_gates=10, cost_update=0,
                                        cost_predict=5000, px=0.0, py=0.0, pz=0.0, vx=0.0, vy=0.0, vz=0.0,
                                        qw=1.0, qx=0.0, qy=0.0, qz=0.0, var_x=1.0, var_y=1.0, var_z=1.0,
                                        var_vx=1e-4, var_vy=1e-4, var_vz=1e-4, var_d0=1e-4, var_d1=1e-4,
                                        var_d2=1e-4, flags=5)),
        ("stats", 3, m.Stats(frames_ok=100, crc_errors=1, framing_errors=2, unknown_types=3, bad_lengths=4,
                             non_finite=5, unknown_anchors=6, time_backwards=7, bad_configs=8, dropped_meas=9,
                             imu_samples=1000, twr_meas=200, tdoa_meas=0, results=190, predictions=100,
                             seq_gaps=0, radio_packets=500, radio_meas=450, radio_no_reference=20,
                             radio_clock=16, radio_expired=5, radio_malformed=4, radio_unknown_type=3,
                             radio_no_position=2, divergences=2, heights=30, bad_values=1, nn_pairs_disabled=3,
                             baseline_rejects=6)),
        ("error", 4, m.Error(code=4, msg_type=5, msg_seq=8, detail=12)),
    ]


def _radio_and_control_vectors() -> list[tuple[str, int, Any]]:
    """The radio level (RADIO, CLOCK_REQ, RADIO_DROP, CLOCK) and the closed loop (SETPOINT, CONTROL)."""
    return [
        ("radio_tdoa2_lpp", 17, _radio(20_000, 0xFF_FFFF_FFFF, 0xBCCF000000000003, _TDOA2_LPP)),
        ("radio_tdoa3", 18, _radio(2**63, 0x12_3456_789A, 0xBCCF000000000005, _TDOA3)),
        ("radio_empty", 19, _radio(0, 0, 0, b"")),
        ("clock_req", 20, m.ClockReq(anchor_id=7)),
        ("radio_drop", 7, m.RadioDrop(meas_seq=17, reason=2, anchor_id=3)),
        ("clock", 8, m.Clock(anchor_id=5, known=1, bucket=4, reserved=0, skew_ppm=-9.875, packets=1234)),
        ("setpoint_hover", 13, m.Setpoint(t_us=3_000_000, mode=1, reserved=0, x=0.0, y=0.0, z=1.0, vx=0.0,
                                          vy=0.0, vz=0.0, ax=0.0, ay=0.0, az=0.0, yaw=0.0)),
        ("setpoint_circle", 14, m.Setpoint(t_us=12_345_678, mode=1, reserved=0, x=1.5, y=-0.25, z=0.75,
                                           vx=-0.0625, vy=0.375, vz=0.0, ax=-0.09375, ay=-0.015625, az=0.0,
                                           yaw=-1.5)),
        ("setpoint_off", 15, m.Setpoint(t_us=0, mode=0, reserved=0, x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0,
                                        vz=0.0, ax=0.0, ay=0.0, az=0.0, yaw=0.0)),
        ("setpoint_nan", 16, m.Setpoint(t_us=10_000, mode=1, reserved=0, x=NAN, y=0.0, z=1.0, vx=0.0, vy=0.0,
                                        vz=0.0, ax=0.0, ay=0.0, az=0.0, yaw=0.0)),
        ("control", 5, m.Control(setpoint_seq=14, mode=1, flags=0, t_us=12_345_678, thrust=0.3125,
                                 rate_x=0.5, rate_y=-0.25, rate_z=0.0, px=1.5, py=-0.25, pz=0.75, vx=-0.0625,
                                 vy=0.375, vz=0.0, qw=1.0, qx=0.0, qy=0.0, qz=0.0, compute=321)),
        ("control_saturated", 6, m.Control(setpoint_seq=0xFFFF, mode=1, flags=15, t_us=2**64 - 1, thrust=0.6,
                                           rate_x=-6.0, rate_y=6.0, rate_z=-1.0, px=-3.0, py=4.0, pz=0.0,
                                           vx=0.0, vy=0.0, vz=-0.5, qw=0.5, qx=0.5, qy=-0.5, qz=0.5,
                                           compute=0)),
    ] + _measurement_vectors()


def _measurement_vectors() -> list[tuple[str, int, Any]]:
    """One vector for each measurement message of a kind added since TWR and TDoA (messages.toml
    `meas_kind`), so a new kind needs no edit here (docs/ARCHITECTURE.md "Adding a measurement kind")."""
    out = []
    for spec in load_spec().messages:
        if spec.meas_kind is None or spec.meas_kind in ("TWR", "TDOA"):
            continue
        cls = m.MESSAGES_BY_ID[spec.msg_id]
        ids = {f.name: 1 + k for k, f in enumerate(spec.fields[1:-1])}
        msg = cls(t_us=9000 + spec.msg_id, **ids, **{spec.fields[-1].name: 1.5})
        out.append((spec.name.lower(), 100 + spec.msg_id, msg))
    return out


def format_fields(msg: Any) -> str:
    parts = []
    for name, wire in msg.FIELDS:
        value = getattr(msg, name)
        if wire == "f32":
            parts.append(f"{name}=f:{struct.unpack('<I', struct.pack('<f', value))[0]:08x}")
        elif wire.startswith("bytes"):
            parts.append(f"{name}=x:{value.hex()}")
        else:
            parts.append(f"{name}={value}")
    return " ".join(parts)


def render() -> str:
    lines = [
        "# uwb-hil golden vectors: GENERATED by `python -m protocol.golden`; checked by "
        "tests/protocol/test_protocol.py",
        "# and firmware_sim/tests/test_proto.c. <name> <seq> <frame hex> <MESSAGE> <field>=<value> ...",
    ]
    for name, seq, msg in _vectors():
        frame = encode_frame(msg, seq)
        fields = format_fields(msg)
        lines.append(f"{name} {seq} {frame.hex()} {msg.NAME}" + (f" {fields}" if fields else ""))
    return "\n".join(lines) + "\n"


def parse(text: str) -> list[dict[str, Any]]:
    out = []
    for line in text.splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, seq, frame_hex, msg_name, *fields = line.split()
        out.append({"name": name, "seq": int(seq), "frame": bytes.fromhex(frame_hex), "msg_name": msg_name,
                    "fields": " ".join(fields)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args(argv)
    text = render()
    current = VECTORS_PATH.read_text() if VECTORS_PATH.exists() else None
    if args.check:
        if current != text:
            print(f"{VECTORS_PATH} differs from what the codec produces", file=sys.stderr)
            return 1
        return 0
    VECTORS_PATH.parent.mkdir(parents=True, exist_ok=True)
    VECTORS_PATH.write_text(text)
    print(f"wrote {VECTORS_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
