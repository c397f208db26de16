#!/usr/bin/env python3
"""Seed corpora for the fuzz targets, from the golden vectors (protocol/golden/vectors.txt).

    python3 make_seeds.py VECTORS OUTDIR      -> OUTDIR/frame_rx/*, OUTDIR/firmware/*

Standard library only (runs before the venv exists). frame_rx seeds: every golden frame alone, all of
them back to back, and a few with garbage around them. firmware seeds: a chunking byte followed by
golden frames, plus short sessions (CONFIG, ANCHORs, IMU and TWR/TDoA around a hovering tag) so that
the fuzzer starts deep inside the estimator rather than at the CRC check; radio sessions (RADIO frames
from four anchors, TDoA2 and TDoA3, that form measurements). radio seeds: the same packets for the
parser + TDoA engine target.
"""

from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli, reflected) bit by bit: the seeds are few and short, and the script stays standard
    library only (protocol/framing.py, which the harness uses, needs crcmod)."""
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0x82F63B78 if crc & 1 else crc >> 1
    return crc ^ 0xFFFFFFFF


def cobs(data: bytes) -> bytes:
    out, block = bytearray(), bytearray()
    for b in data:
        if b == 0:
            out += bytes([len(block) + 1]) + block
            block.clear()
        else:
            block.append(b)
            if len(block) == 254:
                out += b"\xff" + block
                block.clear()
    return bytes(out + bytes([len(block) + 1]) + block)


def frame(msg_id: int, seq: int, payload: bytes) -> bytes:
    body = struct.pack("<BH", msg_id, seq & 0xFFFF) + payload
    return cobs(body + struct.pack("<I", crc32c(body))) + b"\x00"


ANCHORS = [(-3.0, -3.0, 0.2), (3.0, -3.0, 2.5), (3.0, 3.0, 0.2), (-3.0, 3.0, 2.5)]


def session(golden: dict[str, bytes], tdoa: bool, uwb_only: bool) -> bytes:
    """CONFIG (golden, IMU mode with all stages, or UWB-only) + anchors + 0.3 s of hover data."""
    out = bytearray(golden["config_uwb_only" if uwb_only else "config_defaults"])
    seq = 100
    for i, (x, y, z) in enumerate(ANCHORS):
        out += frame(0x03, seq, struct.pack("<Bfff", i, x, y, z))
        seq += 1
    tag = (0.3, -0.2, 1.0)
    for k in range(30):
        t = 1000 + 10_000 * k
        out += frame(0x04, seq, struct.pack("<Qffffff", t, 0.01, -0.02, 9.81, 0.001, 0.0, -0.002))
        seq += 1
        if k % 2:
            a = k % 4
            if tdoa:
                b = (a + 1) % 4
                d = math.dist(tag, ANCHORS[b]) - math.dist(tag, ANCHORS[a])
                out += frame(0x06, seq, struct.pack("<QBBf", t + 500, a, b, d))
            else:
                out += frame(0x05, seq, struct.pack("<QBf", t + 500, a, math.dist(tag, ANCHORS[a])))
            seq += 1
    out += golden["stats_req"]
    return bytes(out)


TS_FREQ = 63.8976e9
TICK_M = 299792458.0 / TS_FREQ


def radio_packets(tdoa2: bool) -> list[tuple[int, int, int, bytes]]:
    """(t_us, tag rx_ts, sender, payload) of a hovering tag among ANCHORS with ideal clocks: each anchor
    transmits every 10 ms and reports what it heard from the others (seq, RX time, ToF), with LPP."""
    tag = (0.3, -0.2, 1.0)
    heard: dict[int, dict[int, tuple[int, int]]] = {a: {} for a in range(len(ANCHORS))}
    seq = [0] * len(ANCHORS)
    out = []
    for k in range(40):
        a = k % len(ANCHORS)
        t_s = 0.001 + 0.0025 * k
        tx = int(t_s * TS_FREQ) & ~0x1FF
        lpp = bytes([0xF0, 0x01]) + struct.pack("<3f", *ANCHORS[a])
        remotes = []
        for b, (s_b, rx_b) in sorted(heard[a].items()):
            tof = int(round(math.dist(ANCHORS[a], ANCHORS[b]) / TICK_M)) + 32951
            remotes.append((b, s_b, rx_b, tof))
        if tdoa2:
            seqs, ts, tofs = [0] * 8, [0] * 8, [0] * 8
            seqs[a], ts[a] = seq[a], tx & 0xFFFFFFFF
            for b, s_b, rx_b, tof in remotes:
                seqs[b], ts[b], tofs[b] = s_b, rx_b, tof
            payload = bytes([0x22]) + bytes(seqs) + struct.pack("<8I", *ts) + struct.pack("<8H", *tofs) + lpp
        else:
            payload = bytes([0x30, seq[a]]) + struct.pack("<I", tx & 0xFFFFFFFF) + bytes([len(remotes)])
            for b, s_b, rx_b, tof in remotes:
                payload += bytes([b, s_b | 0x80]) + struct.pack("<IH", rx_b, tof)
            payload += lpp
        for b in range(len(ANCHORS)):
            if b != a:
                heard[b][a] = (seq[a], (tx + 32951 + int(math.dist(ANCHORS[a], ANCHORS[b]) / TICK_M)) & 0xFFFFFFFF)
        rx = (tx + 32951 + int(math.dist(ANCHORS[a], tag) / TICK_M)) & 0xFFFFFFFFFF
        out.append((int(t_s * 1e6), rx, a, payload))
        seq[a] = (seq[a] + 1) & 0x7F
    return out


def radio_session(golden: dict[str, bytes], tdoa2: bool) -> bytes:
    """CONFIG (UWB-only) + RADIO frames (positions from their LPP) + CLOCK_REQ + STATS_REQ."""
    out = bytearray(golden["config_uwb_only"])
    for i, (t_us, rx, a, payload) in enumerate(radio_packets(tdoa2)):
        body = struct.pack("<QQQB", t_us, rx, 0xBCCF000000000000 | a, len(payload)) + payload.ljust(128, b"\0")
        out += frame(0x09, 200 + i, body)
    out += frame(0x0A, 300, bytes([1])) + golden["stats_req"]
    return bytes(out)


def radio_target_seed(tdoa2: bool) -> bytes:
    """The same packets in the radio target's format: sender, rx_ts (5 B), t_us delta [ms], len, payload."""
    out = bytearray()
    for _t, rx, a, payload in radio_packets(tdoa2):
        out += bytes([a]) + rx.to_bytes(5, "little") + bytes([2, len(payload)]) + payload
    return bytes(out)


def main(vectors: Path, outdir: Path) -> int:
    golden: dict[str, bytes] = {}
    for line in vectors.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, _seq, hexframe = line.split()[:3]
        golden[name] = bytes.fromhex(hexframe)
    if not golden:
        print(f"make_seeds: no vectors in {vectors}", file=sys.stderr)
        return 1
    fr = outdir / "frame_rx"
    fw = outdir / "firmware"
    rd = outdir / "radio"
    for d in (fr, fw, rd):
        d.mkdir(parents=True, exist_ok=True)
    everything = b"".join(golden.values())
    for name, data in golden.items():
        (fr / name).write_bytes(data)
        (fw / name).write_bytes(b"\x00" + data)
    (fr / "all").write_bytes(everything)
    (fr / "garbage_around").write_bytes(b"\x13\x37" * 40 + b"\x00" + everything + b"\xff" * 300)
    (fw / "all_chunked").write_bytes(b"\x05" + everything)
    for i, (tdoa, uwb_only) in enumerate([(False, False), (True, False), (False, True), (True, True)]):
        (fw / f"session_{'tdoa' if tdoa else 'twr'}_{'cv' if uwb_only else 'imu'}").write_bytes(
            bytes([i * 3]) + session(golden, tdoa, uwb_only))
    for tdoa2 in (True, False):
        name = "tdoa2" if tdoa2 else "tdoa3"
        (fw / f"session_radio_{name}").write_bytes(b"\x07" + radio_session(golden, tdoa2))
        (rd / f"packets_{name}").write_bytes(radio_target_seed(tdoa2))
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
