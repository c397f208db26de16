"""Streaming flights to a device: byte-stream preparation, pacing, result collection."""

from harness.stream.results_file import OUTCOME_ERROR, OUTCOME_LOST, OUTCOME_PENDING, OUTCOME_RESULT
from harness.stream.streamer import Pacing, RunResult, Streamer

__all__ = ["OUTCOME_ERROR", "OUTCOME_LOST", "OUTCOME_PENDING", "OUTCOME_RESULT", "Pacing", "RunResult",
           "Streamer"]
