"""Recorded anchor packets (`uwb-hil run --radio-trace FILE`): traffic captured from a real LPS system,
replayed to the firmware's TDoA engine instead of simulated packets. Format (docs/radio.md):

    # comments and blank lines are ignored; an optional header line `t_rx_ticks,sender,packet_hex`
    t_rx_ticks,sender,packet_hex
    1099511000000,3,2205...          (one received packet per line, in reception order)

t_rx_ticks: the tag's DW1000 RX timestamp (40-bit ticks, decimal or 0x hex); sender: the anchor id (0-255)
or the full MAC source address (0x..., the anchor id is its low byte); packet_hex: the LPS payload after
the 21-byte MAC header (TDoA2 / TDoA3 + optional LPP), 1-128 bytes. Tag time is derived from the stamps
(40-bit wraps unwrapped): the first packet is at the flight's first measurement.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from harness.errors import InputError
from harness.flight.data import KIND_TDOA, Flight, RadioStream, UwbStream
from harness.flight.radio_packets import ANCHOR_ADDR_BASE, PAYLOAD_MAX
from harness.twin import lps_packets as lp
from harness.twin.tdoa_engine import MEASUREMENT, TS_FREQ, replay

HEADER = ("t_rx_ticks", "sender", "packet_hex")
MAX_TRACE_BYTES = 1 << 30
WRAP40 = 1 << 40


class RadioTraceError(InputError):
    """A trace file that cannot be replayed; the message names the file and line."""


def _int(text: str, what: str, where: str, hi: int) -> int:
    try:
        v = int(text.strip(), 0)
    except ValueError:
        raise RadioTraceError(f"{where}: {what} {text.strip()!r} is not an integer") from None
    if not 0 <= v <= hi:
        raise RadioTraceError(f"{where}: {what} {v} outside 0..{hi}")
    return v


def _row(line: str, where: str) -> tuple[int, int, bytes]:
    cols = line.split(",")
    if len(cols) != 3:
        raise RadioTraceError(f"{where}: expected 3 columns {','.join(HEADER)}, got {len(cols)}")
    rx = _int(cols[0], "t_rx_ticks", where, WRAP40 - 1)
    sender = _int(cols[1], "sender", where, (1 << 64) - 1)
    try:
        payload = bytes.fromhex(cols[2].strip())
    except ValueError:
        raise RadioTraceError(f"{where}: packet_hex is not hexadecimal bytes") from None
    if not 1 <= len(payload) <= PAYLOAD_MAX:
        raise RadioTraceError(f"{where}: packet of {len(payload)} bytes (1..{PAYLOAD_MAX})")
    if payload[0] not in (lp.TYPE_TDOA2, lp.TYPE_TDOA3):
        raise RadioTraceError(f"{where}: packet type 0x{payload[0]:02x} is neither TDoA2 (0x22) nor TDoA3 (0x30)")
    return rx, sender if sender > 0xFF else ANCHOR_ADDR_BASE | sender, payload


def load_radio_trace(path: Path | str) -> RadioStream:
    """The trace as a radio stream (t_us from 0, rebased by attach_trace)."""
    path = Path(path)
    if path.is_dir():
        raise RadioTraceError(f"{path}: is a directory, not a radio trace file")
    if not path.is_file():
        raise RadioTraceError(f"{path}: no such file")
    if path.stat().st_size > MAX_TRACE_BYTES:
        raise RadioTraceError(f"{path}: larger than {MAX_TRACE_BYTES} bytes")
    rows: list[tuple[int, int, bytes]] = []
    with path.open("r", encoding="ascii", errors="replace") as fh:
        for n, raw in enumerate(fh, start=1):
            line = raw.strip()
            if not line or line.startswith("#") or (not rows and line.replace(" ", "").lower() == ",".join(HEADER)):
                continue
            rows.append(_row(line, f"{path}:{n}"))
    if not rows:
        raise RadioTraceError(f"{path}: no packets")
    types = {r[2][0] for r in rows}
    if len(types) > 1:
        raise RadioTraceError(f"{path}: mixes TDoA2 and TDoA3 packets")
    rx = np.array([r[0] for r in rows], dtype=np.int64)
    ticks = np.concatenate([[0], np.cumsum(np.diff(rx) % WRAP40)])      # 40-bit wraps unwrapped
    payload = np.zeros((len(rows), PAYLOAD_MAX), dtype=np.uint8)
    for k, r in enumerate(rows):
        payload[k, :len(r[2])] = np.frombuffer(r[2], dtype=np.uint8)
    return RadioStream(protocol="tdoa2" if types == {lp.TYPE_TDOA2} else "tdoa3",
                       t_us=np.round(ticks / TS_FREQ * 1e6).astype(np.int64), rx_ts=rx.astype(np.uint64),
                       src_addr=np.array([r[1] for r in rows], dtype=np.uint64),
                       length=np.array([len(r[2]) for r in rows], dtype=np.uint8), payload=payload)


def attach_trace(flight: Flight, radio: RadioStream) -> Flight:
    """The flight with the trace as its radio stream (first packet at the flight's first measurement) and,
    as its measurement level, what the engine twin forms from it (true values from the flight's truth)."""
    t0 = int(flight.uwb.t_us[0]) if len(flight.uwb) else 0
    radio = replace(radio, t_us=radio.t_us + t0)
    payloads = [bytes(radio.payload[k, :int(radio.length[k])]) for k in range(len(radio))]
    _, out = replay(radio.t_us.tolist(), [int(v) for v in radio.rx_ts], [int(v) for v in radio.src_addr], payloads)
    keep = [(int(t), m) for t, (rc, m) in zip(radio.t_us, out) if rc == MEASUREMENT and m is not None]
    ap = {int(i): p for i, p in zip(flight.anchors.ids, flight.anchors.positions)}
    keep = [(t, m) for t, m in keep if m.anchor_a in ap and m.anchor_b in ap]
    tt = np.array([t for t, _ in keep], dtype=np.int64)
    a = np.array([m.anchor_a for _, m in keep], dtype=np.int64)
    b = np.array([m.anchor_b for _, m in keep], dtype=np.int64)
    pos = flight.truth.position_at(tt).reshape(-1, 3)
    pa, pb = np.array([ap[int(i)] for i in a]).reshape(-1, 3), np.array([ap[int(i)] for i in b]).reshape(-1, 3)
    true = np.linalg.norm(pos - pb, axis=1) - np.linalg.norm(pos - pa, axis=1)
    uwb = UwbStream(kind=KIND_TDOA, t_us=tt, anchor_a=a, anchor_b=b,
                    value=np.array([m.diff for _, m in keep], dtype=np.float64), true_value=true)
    meta = dict(flight.meta)
    meta["radio"] = {"protocol": radio.protocol, "trace": True, "packets": len(radio)}
    return replace(flight, name=f"{flight.name}-trace-{radio.protocol}", uwb=uwb, meta=meta, radio=radio)
