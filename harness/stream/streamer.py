"""Stream a flight to a device and collect, per measurement, its RESULT, device cost and round trip.

Pacing modes:
  lockstep  one measurement in flight: send it (with the IMU samples before it), wait for its RESULT;
  windowed  up to `window` measurements in flight (same estimates as lockstep: the device processes
            frames in order, pacing only changes when bytes arrive);
  realtime  frames written at their data timestamps divided by `speed`, as a sensor would deliver them.

Every measurement ends in exactly one outcome: RESULT, ERROR (refused by the device), or LOST (a later
measurement was answered first, or the run ended without an answer). Nothing blocks without a timeout.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from harness.config import EstimatorConfig
from harness.device.channel import DeviceChannel, Replies, as_channel
from harness.errors import DeviceTimeout, UsageError
from harness.flight.data import Flight
from harness.options import DEVICE_TIMEOUT_S, MAX_SPEED, MIN_SPEED
from harness.stream.prepare import PreparedFlight, frame_count, prepare
from harness.stream.results_file import (OUTCOME_ERROR, OUTCOME_LOST, OUTCOME_NO_MEAS, OUTCOME_PENDING,
                                         OUTCOME_RESULT, REC_DEVICE_ERROR, REC_STATS, RESULT_BYTES,
                                         RESULT_BYTES_OFFSET, RESULTS_DTYPE, ResultsWriter)
from protocol import messages as m
from protocol.batch import RESULT_DTYPE
from protocol.framing import DecoderErrors

PACING_MODES = ("lockstep", "windowed", "realtime")


@dataclass(frozen=True)
class Pacing:
    mode: str = "windowed"
    window: int = 64
    speed: float = 1.0

    def __post_init__(self) -> None:
        if self.mode not in PACING_MODES:
            raise UsageError(f"pacing mode must be one of {PACING_MODES}, got {self.mode!r}")
        if self.window < 1:
            raise UsageError("window must be >= 1")
        if not MIN_SPEED <= self.speed <= MAX_SPEED:   # also refuses nan; 1e-300 would wait for ever
            raise UsageError(f"speed must be in [{MIN_SPEED:g}, {MAX_SPEED:g}], got {self.speed!r}")

    @property
    def in_flight(self) -> int:
        return 1 if self.mode == "lockstep" else self.window


@dataclass
class RunResult:
    flight: str
    config: EstimatorConfig
    pacing: Pacing
    results: np.ndarray                      # (M,) RESULTS_DTYPE, one row per UWB measurement
    stats: m.Stats | None                    # device counters after the run
    decoder_errors: DecoderErrors            # what the host could not decode
    errors: list[m.Error] = field(default_factory=list)
    wall_s: float = 0.0
    sim_s: float = 0.0
    # Device counters before the run (STATS counts since power-up): the run's own refusals are the
    # difference. None when not asked: a resumed run, or a link that injects faults (it may drop the query).
    stats_start: m.Stats | None = None
    faults_injected: bool = False            # the link injects faults on purpose (harness.link.faulty)

    @property
    def n_received(self) -> int:
        return int(np.count_nonzero(self.results["outcome"] == OUTCOME_RESULT))

    @property
    def n_lost(self) -> int:
        return int(np.count_nonzero(self.results["outcome"] == OUTCOME_LOST))

    @property
    def realtime_factor(self) -> float:
        """Simulated over wall time; NaN when the wall time is unknown (a resumed run): not infinite."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else float("nan")


@dataclass
class _State:
    results: np.ndarray
    seq_to_meas: dict[int, int]
    resolved_upto: int = 0       # every measurement below this index has an outcome
    max_answered: int = -1
    errors: list[m.Error] = field(default_factory=list)
    stats: m.Stats | None = None
    last_rx: float = 0.0

    def answer(self, seq: int, outcome: int, code: int, now_ns: int) -> int:
        """The pending measurement sent as `seq` answered without a RESULT (an ERROR, a RADIO_DROP): its outcome,
        code and time set; its index, or -1 when `seq` is no pending measurement."""
        k = self.seq_to_meas.pop(seq, -1)
        if k >= 0:
            self.results["outcome"][k] = outcome
            self.results["error_code"][k] = code
            self.results["t_recv_ns"][k] = now_ns
        return k


class Streamer:
    """Drives one device through flights: pacing and bookkeeping. The frames go through the device's
    DeviceChannel (seq, decoder, link and device errors); the device must be started and HELLO-checked."""

    def __init__(self, device: Any, timeout_s: float = DEVICE_TIMEOUT_S) -> None:
        """`device`: a DeviceChannel, or a started device (its `channel` is used)."""
        self.channel: DeviceChannel = as_channel(device)
        self.timeout_s = timeout_s
        self._sent_bytes = 0

    def _write_stream(self, data: bytes, state: _State, writer: ResultsWriter) -> None:
        self.channel.write_stream(data, lambda got: self._absorb(got, state, writer))

    # ------------------------------------------------------------------------------ the run
    def run(self, flight: Flight, config: EstimatorConfig, pacing: Pacing = Pacing(),
            results_path: Path | None = None, progress: Callable[[int, int], None] | None = None,
            include_imu: bool = True, header_extra: dict[str, Any] | None = None,
            writer: ResultsWriter | None = None, reset: bool = True, overwrite: bool = True,
            radio: bool = False) -> RunResult:
        """`header_extra` goes into the results header (e.g. how to rebuild the flight for --resume);
        `writer` replaces the results file writer (resume appends); `reset=False` keeps the device's
        filter state (the CONFIG is sent without reset: a resumed run continues a replayed prefix).
        `radio`: stream the flight's radio packets (one row per packet; OUTCOME_NO_MEAS for those that
        formed no measurement) instead of its measurements; anchor positions then come from their LPP."""
        config.validate()
        ch = self.channel
        n_frames = frame_count(flight, include_imu, radio)     # refuses a flight it cannot stream
        n = len(flight.radio.t_us if (radio and flight.radio is not None) else flight.uwb.t_us)
        results = np.zeros(n, RESULTS_DTYPE)
        state = _State(results=results, seq_to_meas={})
        if writer is None:
            writer = ResultsWriter(results_path, {"flight": flight.name, "config": asdict(config),
                                                  "pacing": asdict(pacing), "n_measurements": n,
                                                  **(header_extra or {})}, overwrite=overwrite)
        t_start = time.perf_counter()
        faulty = bool(getattr(ch.link, "injects_faults", False))
        stats_start: m.Stats | None = None
        try:
            # the set-up barrier's STATS are the counters before this run's frames (a fault-injecting link
            # may have mangled the set-up itself: no start counters then)
            setup_stats = ch.configure(config, None if radio else flight.anchors, reset=reset, timeout=self.timeout_s)
            stats_start = None if faulty else setup_stats
            prep = prepare(flight, ch.reserve(n_frames), include_imu=include_imu, radio=radio)
            assert len(prep.meas_end) == n
            if pacing.mode == "realtime":
                self._run_realtime(prep, pacing, state, writer, progress)
            else:
                self._run_windowed(prep, pacing.in_flight, state, writer, progress)
            self._finish(prep, state, writer)
            state.stats = ch.stats(self.timeout_s)
            writer.write_record({"type": REC_STATS, **asdict(state.stats), "host_decoder": asdict(ch.errors)})
        finally:
            writer.close()
        wall = time.perf_counter() - t_start
        sim = (int(flight.uwb.t_us[-1]) - int(flight.uwb.t_us[0])) * 1e-6 if n else 0.0
        return RunResult(flight=flight.name, config=config, pacing=pacing, results=results, stats=state.stats,
                         decoder_errors=replace(ch.errors), errors=state.errors, wall_s=wall, sim_s=sim,
                         stats_start=stats_start, faults_injected=faulty)

    def _absorb(self, replies: Replies, state: _State, writer: ResultsWriter) -> None:
        got, frames, now_ns = replies.results, replies.frames, replies.t_ns
        res = state.results
        answered: list[int] = []
        if len(got):
            pop = state.seq_to_meas.pop
            found = [pop(s, -1) for s in got["meas_seq"].tolist()]
            idx = np.array(found, dtype=np.int64)
            if -1 in found:
                keep = idx >= 0
                idx, got = idx[keep], got[keep]
            # The RESULT fields are one packed run of bytes in both layouts: copy rows as bytes.
            res_bytes = res.view(np.uint8).reshape(len(res), RESULTS_DTYPE.itemsize)
            got_bytes = np.ascontiguousarray(got).view(np.uint8).reshape(len(got), RESULT_DTYPE.itemsize)
            res_bytes[idx, :RESULT_BYTES] = got_bytes[:, RESULT_BYTES_OFFSET:RESULT_BYTES_OFFSET + RESULT_BYTES]
            res["t_recv_ns"][idx] = now_ns
            res["outcome"][idx] = OUTCOME_RESULT
            answered += idx.tolist()
        for f in frames:
            if isinstance(f.msg, m.Error):
                state.errors.append(f.msg)
                k = state.answer(f.msg.msg_seq, OUTCOME_ERROR, f.msg.code, now_ns)
                if k >= 0:
                    answered.append(k)
                else:
                    # not about a pending measurement (an IMU frame, or DIVERGED after a RESULT): keep it
                    writer.write_record({"type": REC_DEVICE_ERROR, **asdict(f.msg)})
            elif isinstance(f.msg, m.RadioDrop):
                k = state.answer(f.msg.meas_seq, OUTCOME_NO_MEAS, f.msg.reason, now_ns)
                if k >= 0:
                    answered.append(k)
            elif isinstance(f.msg, m.Stats):
                state.stats = f.msg
        if answered:
            state.max_answered = max(state.max_answered, max(answered))
            # The device answers in order: anything older still unanswered was lost on the way.
            lo = state.resolved_upto
            if state.max_answered > lo:
                older = np.nonzero(res["outcome"][lo:state.max_answered] == OUTCOME_PENDING)[0] + lo
                for k in older.tolist():
                    res["outcome"][k] = OUTCOME_LOST
                    state.seq_to_meas.pop(int(res["meas_seq"][k]), None)
            new_hi = state.max_answered + 1
            writer.write_rows(np.arange(lo, new_hi), res[lo:new_hi])
            state.resolved_upto = max(state.resolved_upto, new_hi)
            state.last_rx = time.monotonic()

    def _wait_progress(self, state: _State, writer: ResultsWriter, wait_s: float) -> None:
        got = self.channel.read(wait_s)
        if got:
            self._absorb(got, state, writer)
        # only answers to our measurements reset last_rx: other frames or bytes (a flooding peer) do not
        if time.monotonic() - state.last_rx > self.timeout_s:
            self._probe(state, writer)

    def _probe(self, state: _State, writer: ResultsWriter) -> None:
        """Silence: a dead device raises (DeviceDied from the channel); a live one that answers STATS lost
        our frames."""
        try:
            stats = self.channel.stats(timeout=min(2.0, self.timeout_s))
        except DeviceTimeout:
            raise DeviceTimeout(f"device silent for {self.timeout_s:.1f} s after {state.resolved_upto} "
                                f"measurements (no RESULT, no STATS)") from None
        state.stats = stats
        res = state.results
        pending = np.nonzero(res["outcome"][state.resolved_upto:] == OUTCOME_PENDING)[0] + state.resolved_upto
        sent = pending[res["t_send_ns"][pending] > 0]
        for k in sent.tolist():
            res["outcome"][k] = OUTCOME_LOST
            state.seq_to_meas.pop(int(res["meas_seq"][k]), None)
        if len(sent):
            hi = int(sent[-1]) + 1
            writer.write_rows(np.arange(state.resolved_upto, hi), res[state.resolved_upto:hi])
            state.resolved_upto = hi
        state.last_rx = time.monotonic()

    def _mark_sent(self, prep: PreparedFlight, state: _State, lo: int, hi: int, now_ns: int) -> None:
        res = state.results
        res["t_send_ns"][lo:hi] = now_ns
        res["meas_seq"][lo:hi] = prep.meas_seq[lo:hi]
        for k in range(lo, hi):
            state.seq_to_meas[int(prep.meas_seq[k])] = k

    def _run_windowed(self, prep: PreparedFlight, window: int, state: _State, writer: ResultsWriter,
                      progress: Callable[[int, int], None] | None) -> None:
        n = len(prep.meas_end)
        sent_meas = 0
        sent_bytes = 0
        state.last_rx = time.monotonic()
        while state.resolved_upto < n:
            hi = min(n, state.resolved_upto + window)
            if hi > sent_meas:
                end = int(prep.meas_end[hi - 1])
                now = time.perf_counter_ns()
                self._mark_sent(prep, state, sent_meas, hi, now)
                self._write_stream(prep.stream[sent_bytes:end], state, writer)
                sent_bytes, sent_meas = end, hi
            self._wait_progress(state, writer, 0.05)
            if progress is not None:
                progress(state.resolved_upto, n)
        self._sent_bytes = sent_bytes

    def _run_realtime(self, prep: PreparedFlight, pacing: Pacing, state: _State, writer: ResultsWriter,
                      progress: Callable[[int, int], None] | None) -> None:
        n = len(prep.meas_end)
        if len(prep.event_t_us) == 0:
            self._sent_bytes = 0
            return
        t0_data = int(prep.event_t_us[0])
        t0_wall = time.perf_counter()
        sent_bytes = 0
        sent_meas = 0
        state.last_rx = time.monotonic()
        due_t = (prep.event_t_us - t0_data) / 1e6 / pacing.speed
        n_events = len(prep.event_end)
        e = 0
        while e < n_events or state.resolved_upto < n:
            now = time.perf_counter() - t0_wall
            e_hi = int(np.searchsorted(due_t, now, side="right"))
            if e_hi > e:
                end = int(prep.event_end[e_hi - 1])
                m_hi = int(np.searchsorted(prep.meas_end, end, side="right"))
                self._mark_sent(prep, state, sent_meas, m_hi, time.perf_counter_ns())
                self._write_stream(prep.stream[sent_bytes:end], state, writer)
                sent_bytes, sent_meas, e = end, m_hi, e_hi
            wait = 0.05 if e >= n_events else max(0.0, min(0.05, float(due_t[e]) - now))
            self._wait_progress(state, writer, wait)
            if progress is not None:
                progress(state.resolved_upto, n)
        self._sent_bytes = sent_bytes

    def _finish(self, prep: PreparedFlight, state: _State, writer: ResultsWriter) -> None:
        """Send what follows the last measurement (trailing IMU samples)."""
        if self._sent_bytes < len(prep.stream):
            self._write_stream(prep.stream[self._sent_bytes:], state, writer)
