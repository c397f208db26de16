"""Resume a long simulated flight in slices, as `uwb-hil run` streams it (harness/stream/chunked_run.py), so
resuming half of a 1-hour flight needs about the memory of the plain run, not the whole flight built at
once (issue 27: 8.1 GB against 422 MB).

The checks and the protocol are those of harness/stream/resume.py: the flight's digest (computed over the
slices first, as stream_plan wrote it), its measurement count and the configuration must be the header's;
the recorded part is REPLAYED slice by slice (the first with reset, the others without, as the plain run
sent them) and each slice's results compared with its recorded rows before anything is written; the slice
holding the resume point is split there (resume.split_flight); the rest is streamed with the recorded
pacing and appended with its global indices. The summary flight is the compact one of chunked_run
(measurements and the truth at their times).
"""

from __future__ import annotations

import time
from typing import Any, Callable

from harness.config import EstimatorConfig
from harness.flight.chunked import SimPlan
from harness.flight.data import Flight
from harness.options import DEVICE_TIMEOUT_S
from harness.stream.chunked_run import CHUNK_S, _Compact, _SliceWriter
from harness.stream.digest import FlightDigest
from harness.stream.resume import RecordedRun, ResumeError, replay_differences, run_from_file, split_flight
from harness.stream.results_file import REC_RESUME, LockedResults, ResultsWriter, truncate_partial_line
from harness.stream.streamer import Pacing, RunResult, Streamer


def check_plan(rec: RecordedRun, plan: SimPlan, chunk_s: float = CHUNK_S) -> None:
    """The flight the header's source gives now is the recorded one: name, measurement count, digest."""
    where = f"{rec.path}:1"
    if str(rec.header["flight"]) != plan.name:
        raise ResumeError(f"{where}: the file records flight {rec.header['flight']!r}, its source now gives "
                          f"{plan.name!r}: refusing to mix two flights in one file")
    if plan.n_uwb != rec.n_measurements:
        raise ResumeError(f"{where}: header says {rec.n_measurements} measurements, the rebuilt flight "
                          f"{plan.name!r} has {plan.n_uwb} (different data or simulator version)")
    recorded = rec.header.get("flight_digest")
    if recorded is None:
        return
    digest, n = FlightDigest(), len(plan.bounds(chunk_s))
    for i, piece in enumerate(plan.chunks(chunk_s)):
        digest.update(piece, last=(i + 1 == n))
    if digest.hexdigest() != recorded:
        raise ResumeError(f"{where}: the flight rebuilt from the header's source differs from the one recorded "
                          f"(digest {digest.hexdigest()}, recorded {recorded}): the simulator changed; start a new run")


class _Resumer:
    """The state of one sliced resume: replay up to k0, then stream and append."""

    def __init__(self, device: Any, rec: RecordedRun, locked: LockedResults, timeout_s: float,
                 progress: Callable[[int, int], None] | None) -> None:
        self.rec, self.locked, self.progress = rec, locked, progress
        self.streamer = Streamer(device, timeout_s=timeout_s)
        self.k0 = rec.next_index
        # the recorded rows, k0 of them (the columns they come from are freed as copied); dropped once replayed
        self.recorded: Any = rec.records.results_array(self.k0, take=True)
        pacing = rec.pacing()
        self.pacing = pacing
        self.replay_pacing = Pacing("windowed", pacing.window if pacing.mode != "lockstep" else 64)
        self.writer: _SliceWriter | None = None
        self.info: dict[str, Any] = {"resumed_at": self.k0, "replayed": 0, "replay_mismatches": 0, "appended": 0}

    def replay(self, piece: Flight, cfg: EstimatorConfig, first_index: int, reset: bool) -> None:
        run = self.streamer.run(piece, cfg, self.replay_pacing, reset=reset)
        n = len(piece.uwb)
        n_diff, first = replay_differences(run.results, self.recorded[first_index:first_index + n])
        if n_diff:
            raise ResumeError(f"{self.rec.path}: the replay of the recorded part differs from its records at {n_diff} "
                              f"of {n} measurements of the slice from {first_index} beyond float tolerance (first: "
                              f"{first}, counted within the slice): the file was edited or another firmware wrote "
                              "it; file left unchanged")
        self.info["replayed"] += n
        if first_index + n >= self.k0:
            self.recorded = None          # every recorded row is checked: the memory goes back

    def append(self, piece: Flight, cfg: EstimatorConfig, first_index: int, reset: bool) -> None:
        if self.writer is None:
            self.info["partial_line_bytes_dropped"] = truncate_partial_line(self.locked.fh, self.rec.path)
            inner = ResultsWriter(None, None, locked=self.locked)
            self.locked.fh.seek(0, 2)
            inner.write_record({"type": REC_RESUME, **self.info, "segment": self.rec.segments + 1,
                                "time": time.strftime("%Y-%m-%dT%H:%M:%S")})
            self.writer = _SliceWriter(inner)
        self.writer.offset = first_index
        total = self.rec.n_measurements

        def slice_progress(k: int, n: int) -> None:
            if self.progress is not None:
                self.progress(first_index + k, total)

        self.streamer.run(piece, cfg, self.pacing, writer=self.writer, reset=reset,  # type: ignore[arg-type]
                          progress=slice_progress)
        self.info["appended"] += len(piece.uwb)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.inner.close()


def resume_plan(device: Any, rec: RecordedRun, plan: SimPlan, config: Callable[[Flight], EstimatorConfig],
                locked: LockedResults, timeout_s: float = DEVICE_TIMEOUT_S,
                progress: Callable[[int, int], None] | None = None,
                chunk_s: float = CHUNK_S) -> tuple[RunResult, Flight, dict[str, Any]]:
    """Replay the recorded part and stream the rest of `plan`'s flight slice by slice, appending to the
    (locked) file. Returns the whole-flight RunResult (read back from the file), the compact summary
    flight, and what the resume did. `config(first slice)` must give the recorded configuration."""
    compact = _Compact(plan.n_uwb, (plan.sched_t, plan.sched_a, plan.sched_b))
    if rec.complete:         # nothing to stream: the summary flight only
        pieces = iter(plan.chunks(chunk_s))
        first = next(pieces)
        for piece in (first, *pieces):
            compact.add(piece)
        return run_from_file(rec.path, compact.flight(first)), compact.flight(first), {
            "resumed_at": rec.next_index, "replayed": 0, "replay_mismatches": 0, "appended": 0,
            "note": "nothing to resume: every measurement has a result"}
    res = _Resumer(device, rec, locked, timeout_s, progress)
    first: Flight | None = None
    done = 0
    t0 = time.perf_counter()
    try:
        for i, piece in enumerate(plan.chunks(chunk_s)):
            if first is None:
                first = piece
                cfg = config(piece)
                if rec.config() != cfg:
                    raise ResumeError(f"{rec.path}:1: the recorded configuration differs from the one its source "
                                      "gives now")
            n = len(piece.uwb)
            compact.add(piece)
            _resume_slice(res, piece, cfg, done, reset=(i == 0))
            done += n
    finally:
        res.close()
    if first is None:
        raise ResumeError(f"{rec.path}: the flight has no slice to stream")
    res.info["replay_s"] = round(time.perf_counter() - t0, 3)
    flight = compact.flight(first)
    return run_from_file(rec.path, flight), flight, res.info


def _resume_slice(res: _Resumer, piece: Flight, cfg: EstimatorConfig, done: int, reset: bool) -> None:
    """One slice: replayed, streamed, or split at the resume point (replayed part, then the rest)."""
    n, k0 = len(piece.uwb), res.k0
    if done + n <= k0:
        res.replay(piece, cfg, done, reset)
        return
    if done >= k0:
        res.append(piece, cfg, done, reset=reset and k0 == 0)
        return
    before, after = split_flight(piece, k0 - done)
    assert before is not None and after is not None
    res.replay(before, cfg, done, reset)
    res.append(after, cfg, k0, reset=False)


__all__ = ["check_plan", "resume_plan"]
