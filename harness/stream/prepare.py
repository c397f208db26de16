"""Turn a Flight into the exact byte stream a device will receive (encoded once, with numpy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness.errors import InputError
from harness.flight.data import SOURCE_ORDER, Flight, Source, merge_order
from harness.kinds import kind_of
from protocol.batch import encode_rows
from protocol import messages as m


@dataclass(frozen=True)
class PreparedFlight:
    """The flight as bytes: `stream[:meas_end[k]]` holds everything up to and including measurement k."""

    stream: bytes
    meas_end: np.ndarray      # (M,) byte offset just after measurement k's frame
    meas_seq: np.ndarray      # (M,) uint16 seq of measurement k's frame
    event_t_us: np.ndarray    # (E,) timestamps of all frames in stream order
    event_end: np.ndarray     # (E,) byte offset just after each frame
    n_imu: int
    next_seq: int             # first seq after the stream


def frame_count(flight: Flight, include_imu: bool = True, radio: bool = False) -> int:
    """How many frames `prepare` makes of the flight (the seqs to reserve); refuses a flight that cannot
    be streamed so."""
    flight.validate()
    if radio and flight.radio is None:
        raise InputError(f"{flight.name}: no radio-level stream (simulate_radio / radio_from_recording)")
    n_imu = len(flight.imu) if (include_imu and flight.has_imu and flight.imu is not None) else 0
    n_uwb = len(flight.radio.t_us) if (radio and flight.radio is not None) else len(flight.uwb)
    n_aux = len(flight.aux) if flight.aux is not None else 0
    return n_imu + n_uwb + (len(flight.height) if flight.height is not None else 0) + n_aux


def _radio_rows(flight: Flight, seqs: np.ndarray) -> np.ndarray:
    r = flight.radio
    assert r is not None
    payload = np.ascontiguousarray(r.payload, dtype=np.uint8).view(f"S{r.payload.shape[1]}")[:, 0]
    return encode_rows(m.Radio, {"t_us": r.t_us, "rx_ts": r.rx_ts, "src_addr": r.src_addr, "length": r.length,
                                 "payload": payload}, seqs)


def prepare(flight: Flight, seq0: int, include_imu: bool = True, radio: bool = False) -> PreparedFlight:
    """Encode every IMU sample, HEIGHT pseudo-measurement, auxiliary and UWB measurement of the flight, merged
    in time order (flight/data.py merge_order: IMU, HEIGHT, AUX, then UWB at equal times). radio: the flight's
    radio packets (RADIO frames) take the place of its measurements (the auxiliary ones are still sent)."""
    n_frames = frame_count(flight, include_imu, radio)
    u, aux = flight.uwb, flight.aux
    imu = flight.imu if (include_imu and flight.has_imu) else None
    hgt = flight.height
    uwb_t = flight.radio.t_us if (radio and flight.radio is not None) else u.t_us
    times = {Source.UWB: uwb_t}
    if imu is not None:
        times[Source.IMU] = imu.t_us
    if hgt is not None:
        times[Source.HEIGHT] = hgt.t_us
    if aux is not None:
        times[Source.AUX] = aux.t_us
    t, _, order = merge_order(times)               # rows: IMU, HEIGHT, AUX, then UWB (SOURCE_ORDER)
    assert len(order) == n_frames
    pos_of = np.empty_like(order)
    pos_of[order] = np.arange(len(order))          # stream position of each source row
    seqs = (seq0 + pos_of) & 0xFFFF
    bounds = np.cumsum([0] + [len(times.get(src, ())) for src in SOURCE_ORDER])
    rows_of = {src: slice(int(bounds[k]), int(bounds[k + 1])) for k, src in enumerate(SOURCE_ORDER)}
    imu_rows_of, hgt_rows_of, uwb_rows_of = rows_of[Source.IMU], rows_of[Source.HEIGHT], rows_of[Source.UWB]
    n_imu, n_h = imu_rows_of.stop - imu_rows_of.start, hgt_rows_of.stop - hgt_rows_of.start

    if radio:
        uwb_rows = _radio_rows(flight, seqs[uwb_rows_of])
    else:
        kind = kind_of(u.kind)
        uwb_rows = encode_rows(kind.message, kind.wire_columns(u), seqs[uwb_rows_of])
    parts = [(uwb_rows_of, uwb_rows)]
    if imu is not None:
        parts.append((imu_rows_of, encode_rows(m.Imu, {
            "t_us": imu.t_us, "ax": imu.acc[:, 0], "ay": imu.acc[:, 1], "az": imu.acc[:, 2],
            "gx": imu.gyro[:, 0], "gy": imu.gyro[:, 1], "gz": imu.gyro[:, 2]}, seqs[imu_rows_of])))
    if hgt is not None:
        parts.append((hgt_rows_of, encode_rows(m.Height, {
            "t_us": hgt.t_us, "z": hgt.z, "std": np.full(n_h, hgt.std)}, seqs[hgt_rows_of])))
    if aux is not None:
        aux_kind = kind_of(aux.kind)
        parts.append((rows_of[Source.AUX], encode_rows(aux_kind.message, aux_kind.wire_columns(aux),
                                                       seqs[rows_of[Source.AUX]])))
    sizes = np.empty(len(order), dtype=np.int64)
    for rows_of, rows in parts:
        sizes[pos_of[rows_of]] = rows.shape[1]
    ends = np.cumsum(sizes)
    starts = ends - sizes
    buf = np.empty(int(ends[-1]) if len(ends) else 0, dtype=np.uint8)
    for rows_of, rows in parts:
        buf[starts[pos_of[rows_of]][:, None] + np.arange(rows.shape[1])] = rows
    return PreparedFlight(
        stream=buf.tobytes(),
        meas_end=ends[pos_of[uwb_rows_of]],
        meas_seq=seqs[uwb_rows_of].astype(np.uint16),
        event_t_us=t[order],
        event_end=ends,
        n_imu=n_imu,
        next_seq=(seq0 + len(order)) & 0xFFFF,
    )
