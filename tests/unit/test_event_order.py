"""One event-ordering rule (flight/data.py merge_order): by time, then IMU, HEIGHT, AUX, UWB at equal times; the
twin's Flight.events() and the streamer's byte stream (stream/prepare.py) follow it."""

from __future__ import annotations

import numpy as np

from harness.flight.data import (KIND_TOF, KIND_TWR, SOURCE_ORDER, Anchors, Flight, HeightStream, ImuStream, Source, Truth,
                                 UwbStream, merge_order)
from harness.stream.prepare import prepare
from protocol.framing import FrameDecoder


def _flight() -> Flight:
    t_imu = np.array([0, 1000, 2000, 3000], np.int64)
    t_uwb = np.array([1000, 3000], np.int64)
    return Flight(name="f", anchors=Anchors(np.array([0, 1]), np.array([[0.0, 0, 0], [3.0, 0, 0]])),
                  truth=Truth(t_imu, np.zeros((4, 3))),
                  uwb=UwbStream(kind=KIND_TWR, t_us=t_uwb, anchor_a=np.array([0, 1]), anchor_b=np.array([0, 0]),
                                value=np.array([1.0, 2.0])),
                  imu=ImuStream(t_imu, np.zeros((4, 3)), np.zeros((4, 3))),
                  height=HeightStream(np.array([1000, 2500], np.int64), np.array([0.5, 0.6]), 0.05),
                  aux=UwbStream(kind=KIND_TOF, t_us=np.array([3000], np.int64), anchor_a=np.array([-1]),
                                anchor_b=np.array([-1]), value=np.array([0.4])))


def test_equal_times_go_imu_height_aux_uwb() -> None:
    assert SOURCE_ORDER == (Source.IMU, Source.HEIGHT, Source.AUX, Source.UWB)
    t, src, order = merge_order({Source.UWB: np.array([5, 7]), Source.IMU: np.array([5, 6]),
                                 Source.HEIGHT: np.array([5]), Source.AUX: np.array([5])})
    assert t[order].tolist() == [5, 5, 5, 5, 6, 7]
    assert [Source(s) for s in src[order]] == [Source.IMU, Source.HEIGHT, Source.AUX, Source.UWB, Source.IMU,
                                               Source.UWB]


def test_the_twin_and_the_stream_see_the_same_order() -> None:
    flight = _flight()
    events = list(flight.events())
    assert [(t, s.name, i) for t, s, i in events] == [
        (0, "IMU", 0), (1000, "IMU", 1), (1000, "HEIGHT", 0), (1000, "UWB", 0), (2000, "IMU", 2),
        (2500, "HEIGHT", 1), (3000, "IMU", 3), (3000, "AUX", 0), (3000, "UWB", 1)]
    prep = prepare(flight, seq0=10)
    frames = FrameDecoder().feed(prep.stream)
    names = {"Imu": Source.IMU, "Height": Source.HEIGHT, "Tof": Source.AUX, "Twr": Source.UWB}
    assert [names[type(f.msg).__name__] for f in frames] == [s for _, s, _ in events]
    assert prep.event_t_us.tolist() == [t for t, _, _ in events]
    assert [f.seq for f in frames] == list(range(10, 19))
    assert prep.meas_seq.tolist() == [13, 18]      # the UWB measurements' frames (the results' rows)


def test_a_resume_split_keeps_the_auxiliary_measurements_in_stream_order() -> None:
    """run --resume streams a prefix and the rest: together the same frames, auxiliary ones included."""
    from dataclasses import replace

    from harness.stream.resume import split_flight
    flight = replace(_flight(), height=None)      # a run with heights is not resumed in parts
    prefix, suffix = split_flight(flight, 1)
    assert prefix is not None and suffix is not None
    assert prefix.aux is not None and len(prefix.aux) == 0 and suffix.aux is not None and len(suffix.aux) == 1
    both = [(t, s) for t, s, _ in prefix.events()] + [(t, s) for t, s, _ in suffix.events()]
    assert both == [(t, s) for t, s, _ in flight.events()]
