"""Stream a flight given as consecutive slices (harness/flight/chunked.py) through one device.

Each slice goes out as a Streamer run; the first resets the filter, the next ones send their CONFIG
without reset, so the device sees one continuous flight (tests/device/test_streaming.py: same estimates as the
whole flight). What is kept across slices is compact: the RESULT rows (one per measurement), and for
the summary a `Flight` holding only the measurements and the true position at each measurement time
(so `run_summary` computes the same accuracy as with the whole flight). The 1 kHz IMU samples and the
1 kHz truth of a slice are dropped once it has been streamed.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from harness.config import EstimatorConfig
from harness.flight.chunked import SimPlan
from harness.flight.data import Flight, Truth, UwbStream
from harness.stream.digest import FlightDigest
from harness.stream.results_file import RESULTS_DTYPE, ResultsWriter
from harness.stream.streamer import Pacing, RunResult, Streamer

#: slice length: short enough to keep memory small, long enough that the per-slice setup and pipeline
#: drain cost nothing measurable (a 30 s slice is ~36k frames)
CHUNK_S = 30.0
#: `uwb-hil run` streams simulated flights longer than this in slices (shorter ones are built whole)
STREAM_ABOVE_S = 120.0


@dataclass
class ChunkedRun:
    run: RunResult        # every measurement's RESULT row, device STATS after the last slice
    flight: Flight        # compact: measurements + truth at measurement times (no IMU)
    chunks: int


class _SliceWriter:
    """One results file for all slices: rows indexed over the whole flight; closed at the very end."""

    def __init__(self, inner: ResultsWriter) -> None:
        self.inner = inner
        self.offset = 0

    def write_rows(self, idx: np.ndarray, rows: np.ndarray) -> None:
        self.inner.write_rows(idx + self.offset, rows)

    def write_record(self, record: dict[str, Any]) -> None:
        self.inner.write_record(record)

    def close(self) -> None:
        """Called by Streamer.run after each slice: the file stays open for the next one."""


class _Compact:
    """Accumulates the measurements and the truth at their times, slice by slice (into preallocated
    arrays when the flight's total is known: no concatenation copy at the end)."""

    _COLS = (("t_us", np.int64, ()), ("a", np.int64, ()), ("b", np.int64, ()), ("value", np.float64, ()),
             ("truth", np.float64, (3,)))

    def __init__(self, n: int | None, schedule: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        self.n = 0
        self.kind = 0
        self.cols = {name: np.zeros((n or 0, *shape), dtype) for name, dtype, shape in self._COLS
                     if schedule is None or name not in ("t_us", "a", "b")}
        # the slices' times and anchors are those of a known schedule (a SimPlan's): kept once, not copied
        self.shared = dict(zip(("t_us", "a", "b"), schedule)) if schedule is not None else {}

    def add(self, piece: Flight) -> None:
        u = piece.uwb
        self.kind = u.kind
        new = {"t_us": u.t_us, "a": u.anchor_a, "b": u.anchor_b, "value": u.value,
               "truth": piece.truth.position_at(u.t_us)}
        k = len(u)
        for name, arr in new.items():
            if name in self.shared:
                if not np.array_equal(self.shared[name][self.n:self.n + k], arr):
                    raise ValueError(f"stream_chunks: slice {name} differs from the schedule")
                continue
            col = self.cols[name]
            if self.n + k > len(col):       # total unknown (or exceeded): grow
                col = self.cols[name] = np.concatenate([col[:self.n], np.zeros((max(k, self.n),) + col.shape[1:],
                                                                               col.dtype)])
            col[self.n:self.n + k] = arr
        self.n += k

    def flight(self, first: Flight) -> Flight:
        c = {name: col[:self.n] for name, col in {**self.cols, **self.shared}.items()}
        uwb = UwbStream(kind=self.kind, t_us=c["t_us"], anchor_a=c["a"], anchor_b=c["b"], value=c["value"])
        # truth sampled exactly at the measurement times: interpolating it there gives these values back
        truth = Truth(t_us=c["t_us"], pos=c["truth"])
        return replace(first, uwb=uwb, truth=truth, imu=None, meta={**first.meta, "compact": True})


class _Rows:
    """The slices' RESULT rows: in one preallocated array when the flight's total is known (no concatenation
    copy at the end), else (or past it) one array per slice."""

    def __init__(self, n: int | None) -> None:
        self.filled = np.zeros(n, RESULTS_DTYPE) if n else None
        self.extra: list[np.ndarray] = []

    def add(self, results: np.ndarray, done: int) -> None:
        """The rows of the slice that starts at measurement `done`."""
        if self.filled is not None and done + len(results) <= len(self.filled):
            self.filled[done:done + len(results)] = results
        else:
            self.extra.append(results)

    def gathered(self, done: int) -> np.ndarray:
        """Every row, in order, once `done` measurements were streamed."""
        if self.filled is not None and not self.extra and done == len(self.filled):
            return self.filled
        return np.concatenate(([self.filled[:done]] if self.filled is not None else []) + self.extra)


def stream_chunks(streamer: Streamer, pieces: Iterable[Flight],
                  config: EstimatorConfig | Callable[[Flight], EstimatorConfig], pacing: Pacing = Pacing(),
                  n_measurements: int | None = None, results_path: Path | None = None,
                  header_extra: dict[str, Any] | None = None,
                  progress: Callable[[int, int], None] | None = None, overwrite: bool = True,
                  schedule: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> ChunkedRun:
    """Stream `pieces` (consecutive slices of one flight) as one run. `config` may be a function of the
    first slice (e.g. session.config_for); `n_measurements` (the whole flight's) goes into the header
    and the progress total; `schedule` (times, anchor a, anchor b of every measurement, when known) is
    referenced by the summary flight instead of copied."""
    rows = _Rows(n_measurements)
    errors: list[Any] = []
    compact = _Compact(n_measurements, schedule)
    writer: _SliceWriter | None = None
    first: Flight | None = None
    cfg: EstimatorConfig | None = None
    last: RunResult | None = None
    opening: RunResult | None = None    # the first slice's run: the device counters before the whole run
    done = slices = 0
    t0 = time.perf_counter()
    try:
        for i, piece in enumerate(pieces):
            if first is None:
                first = piece
                cfg = config(piece) if callable(config) else config
                header = {"flight": piece.name, "config": asdict(cfg), "pacing": asdict(pacing),
                          "n_measurements": n_measurements, **(header_extra or {})}
                writer = _SliceWriter(ResultsWriter(results_path, header, overwrite=overwrite))
            assert cfg is not None and writer is not None
            total = n_measurements or 0

            def slice_progress(k: int, n: int, base: int = done) -> None:
                if progress is not None:
                    progress(base + k, max(total, base + n))

            last = streamer.run(piece, cfg, pacing, writer=writer, reset=(i == 0),  # type: ignore[arg-type]
                                progress=slice_progress)
            rows.add(last.results, done)
            errors += last.errors
            opening = opening or last
            compact.add(piece)
            slices += 1
            done += len(piece.uwb)
            writer.offset = done
    finally:
        if writer is not None:
            writer.inner.close()
    if first is None or last is None or cfg is None:
        raise ValueError("stream_chunks: no slice to stream")
    flight = compact.flight(first)
    results = rows.gathered(done)
    t = flight.uwb.t_us
    sim = (int(t[-1]) - int(t[0])) * 1e-6 if len(t) else 0.0
    run = RunResult(flight=first.name, config=cfg, pacing=pacing, results=results, stats=last.stats,
                    decoder_errors=last.decoder_errors, errors=errors, wall_s=time.perf_counter() - t0, sim_s=sim,
                    stats_start=opening.stats_start if opening else None, faults_injected=last.faults_injected)
    return ChunkedRun(run=run, flight=flight, chunks=slices)


def stream_plan(streamer: Streamer, plan: SimPlan, config: Callable[[Flight], EstimatorConfig],
                pacing: Pacing = Pacing(), chunk_s: float = CHUNK_S, results_path: Path | None = None,
                header_extra: dict[str, Any] | None = None, progress: Callable[[int, int], None] | None = None,
                overwrite: bool = True) -> ChunkedRun:
    """A simulated flight built and streamed slice by slice. With a results file, the flight's digest
    (for --resume) is computed first in a separate pass over the slices, as it goes into the header."""
    header = dict(header_extra or {})
    if results_path is not None:
        digest = FlightDigest()
        bounds = plan.bounds(chunk_s)
        for i, piece in enumerate(plan.chunks(chunk_s)):
            digest.update(piece, last=(i + 1 == len(bounds)))
        header["flight_digest"] = digest.hexdigest()
    return stream_chunks(streamer, plan.chunks(chunk_s), config, pacing, n_measurements=plan.n_uwb,
                         results_path=results_path, header_extra=header, progress=progress, overwrite=overwrite,
                         schedule=(plan.sched_t, plan.sched_a, plan.sched_b))


__all__ = ["CHUNK_S", "STREAM_ABOVE_S", "ChunkedRun", "stream_chunks", "stream_plan"]
