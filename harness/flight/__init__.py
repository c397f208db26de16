"""Flights: the time-ordered sensor stream a device is fed, plus the ground truth that stays on the host."""

from harness.flight.data import Anchors, Flight, ImuStream, Truth, UwbStream, KIND_TDOA, KIND_TWR

__all__ = ["Anchors", "Flight", "ImuStream", "Truth", "UwbStream", "KIND_TDOA", "KIND_TWR"]
