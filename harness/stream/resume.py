"""Resume an interrupted run from its results file (`uwb-hil run --resume RESULTS.jsonl`).

The results file (JSON Lines, written and flushed by the streamer as results arrive) starts with a header
holding the flight's source (scenario + seed, or recording path), the exact EstimatorConfig and the
pacing; then one line per measurement, in measurement order. A run stopped by a dead or hung device
keeps every line written before the failure; a partial last line (the harness itself killed mid-write)
is ignored.

How resume re-initialises the device: the device is fresh (power-up state), so the harness first
REPLAYS the recorded part of the flight (measurements 0..k0-1 with their IMU samples, windowed pacing,
nothing recorded) with the same CONFIG (reset) and anchors. The firmware is deterministic, so this
rebuilds exactly the filter state the interrupted run had after measurement k0-1; the replayed results
are compared with the recorded lines: any difference beyond float tolerance refuses the resume (the
file was edited, or another firmware computed it) and leaves the file unchanged. Before that, the
rebuilt flight (its digest), configuration and the device (firmware build, model hash) must be the
ones in the header. Then the rest of the flight is streamed with the recorded pacing, after a CONFIG
*without* reset (the filter carries on), and its results are appended to the same file with their
global indices (a partial last line is cut first, and reported). The file is locked throughout
(results_file.py). The final summary is computed over the whole flight from the file.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from harness.config import EstimatorConfig
from harness.errors import ResultsFileError
from harness.flight.data import Flight
from harness.options import DEVICE_TIMEOUT_S
from harness.stream.digest import flight_digest
from harness.stream.results_file import (OUTCOME_PENDING, OUTCOME_RESULT, REC_RESUME, LockedResults, ResultsWriter,
                                         RunRecords, read_run, truncate_partial_line)
from harness.stream.streamer import Pacing, RunResult, Streamer
from protocol import messages as m
from protocol.framing import DecoderErrors

#: fields that must be equal between a replayed prefix and the recorded results: exactly (integers) or
#: within REPLAY_RTOL / REPLAY_ATOL (floats: a board may round differently in the last bit)
REPLAY_EXACT = ("status", "t_us")
REPLAY_FIELDS = ("innovation", "innovation_var", "bias", "px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz",
                 "var_x", "var_y", "var_z", "var_vx", "var_vy", "var_vz")
REPLAY_RTOL, REPLAY_ATOL = 1e-5, 1e-6
#: header entries of the device that recorded the run, which the resuming device must match
DEVICE_KEYS = ("proto_version", "firmware", "build_id", "target", "model_hash")


class ResumeError(ResultsFileError):
    """The results file cannot be resumed (missing, malformed, or inconsistent with its flight)."""


@dataclass
class RecordedRun:
    """A results file read for a resume (results_file.read_run) with what the resume needs of it."""
    records: RunRecords

    @property
    def path(self) -> Path:
        return self.records.path

    @property
    def header(self) -> dict[str, Any]:
        return self.records.header

    @property
    def segments(self) -> int:
        return self.records.segments

    @property
    def ignored_partial_line(self) -> bool:
        return self.records.partial_last_line

    @property
    def n_measurements(self) -> int:
        return int(self.header["n_measurements"])

    @property
    def next_index(self) -> int:
        return len(self.records)

    @property
    def complete(self) -> bool:
        return self.next_index >= self.n_measurements

    def config(self) -> EstimatorConfig:
        try:
            return EstimatorConfig(**self.header["config"])
        except (KeyError, TypeError) as exc:
            raise ResumeError(f"{self.path}:1: header field 'config' is not an EstimatorConfig: {exc}") from None

    def pacing(self) -> Pacing:
        try:
            return Pacing(**self.header["pacing"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ResumeError(f"{self.path}:1: header field 'pacing' is invalid: {exc}") from None

    def results_array(self) -> np.ndarray:
        """The recorded rows as RESULTS_DTYPE (rows not yet recorded stay OUTCOME_PENDING)."""
        return self.records.results_array(self.n_measurements)


def read_results(path: Path) -> RecordedRun:
    """Read a results file for a resume; errors name the file, line and field. A cut last line (the harness
    killed mid-write) is ignored: that measurement is run again."""
    records = read_run(Path(path), ResumeError, allow_partial=True,
                       header_keys=("flight", "config", "pacing", "n_measurements"))
    if len(records) > int(records.header["n_measurements"]):
        raise ResumeError(f"{path}: {len(records)} results for a flight of {records.header['n_measurements']} "
                          "measurements")
    return RecordedRun(records)


def split_flight(flight: Flight, k0: int) -> tuple[Flight | None, Flight | None]:
    """(measurements 0..k0-1 with the IMU samples streamed before them, the rest). Concatenated they are
    exactly the original stream (IMU samples go before a measurement with the same time stamp)."""
    u = flight.uwb
    m_total = len(u)
    if not 0 <= k0 <= m_total:
        raise ResumeError(f"resume point {k0} outside the flight's {m_total} measurements")
    if k0 == 0:
        return None, flight
    t_cut = int(u.t_us[k0 - 1])

    def take_uwb(sel: slice) -> Any:
        return replace(u, **{f.name: getattr(u, f.name)[sel] for f in fields(u)
                             if isinstance(getattr(u, f.name), np.ndarray) and getattr(u, f.name).shape[:1] == (m_total,)})

    def take_imu(mask: np.ndarray) -> Any:
        imu = flight.imu
        if imu is None:
            return None
        n = len(imu)
        return replace(imu, **{f.name: getattr(imu, f.name)[mask] for f in fields(imu)
                               if isinstance(getattr(imu, f.name), np.ndarray) and getattr(imu, f.name).shape[:1] == (n,)})

    def take_aux(before: bool) -> Any:
        a = flight.aux     # auxiliary measurements go before a measurement with the same time stamp, as IMU samples
        if a is None:
            return None
        k = int(np.searchsorted(a.t_us, t_cut, side="right"))
        return a.take(slice(0, k) if before else slice(k, len(a)))

    imu_t = flight.imu.t_us if flight.imu is not None else np.zeros(0, np.int64)
    prefix = replace(flight, uwb=take_uwb(slice(0, k0)), imu=take_imu(imu_t <= t_cut), aux=take_aux(True))
    suffix = replace(flight, uwb=take_uwb(slice(k0, m_total)), imu=take_imu(imu_t > t_cut),
                     aux=take_aux(False)) if k0 < m_total else None
    return prefix, suffix


def replay_differences(replayed: np.ndarray, recorded: np.ndarray) -> tuple[int, str]:
    """Measurements whose replay differs from the record beyond float tolerance (a recorded result the
    replay does not reproduce, or a field off), and a description of the first one."""
    diff = replayed["outcome"] != recorded["outcome"]
    both = (replayed["outcome"] == OUTCOME_RESULT) & (recorded["outcome"] == OUTCOME_RESULT)
    first: dict[int, str] = {}
    for name in (*REPLAY_EXACT, *REPLAY_FIELDS):
        a, b = replayed[name], recorded[name]
        bad = both & ((a != b) if name in REPLAY_EXACT else
                      ~np.isclose(a, b, rtol=REPLAY_RTOL, atol=REPLAY_ATOL, equal_nan=True))
        diff |= bad
        k = np.flatnonzero(bad)
        if k.size and int(k[0]) not in first:
            first[int(k[0])] = f"{name} replayed {a[k[0]]!r}, recorded {b[k[0]]!r}"
    for k in np.flatnonzero(replayed["outcome"] != recorded["outcome"])[:1]:
        first.setdefault(int(k), f"outcome replayed {int(replayed['outcome'][k])}, recorded "
                                 f"{int(recorded['outcome'][k])}")
    n = int(np.count_nonzero(diff))
    return n, (f"measurement {min(first)}: {first[min(first)]}" if first else "")


def replay_mismatches(replayed: np.ndarray, recorded: np.ndarray) -> int:
    return replay_differences(replayed, recorded)[0]


def check_resumable(rec: RecordedRun, flight: Flight, config: EstimatorConfig,
                    device: dict[str, Any] | None) -> None:
    """Refuse to resume with another flight, configuration or firmware than the file records."""
    where = f"{rec.path}:1"
    if str(rec.header["flight"]) != flight.name:
        raise ResumeError(f"{where}: the file records flight {rec.header['flight']!r}, its source now gives "
                          f"{flight.name!r}: refusing to mix two flights in one file")
    if len(flight.uwb) != rec.n_measurements:
        raise ResumeError(f"{where}: header says {rec.n_measurements} measurements, the rebuilt flight "
                          f"{flight.name!r} has {len(flight.uwb)} (different data or simulator version)")
    recorded = rec.header.get("flight_digest")
    if recorded is not None and recorded != flight_digest(flight):
        raise ResumeError(f"{where}: the flight rebuilt from the header's source differs from the one recorded "
                          f"(digest {flight_digest(flight)}, recorded {recorded}): the recording was edited or "
                          "replaced, or the simulator changed; start a new run")
    if rec.config() != config:
        diff = [f"{k} {v!r} (now {getattr(config, k)!r})" for k, v in vars(rec.config()).items()
                if getattr(config, k) != v]
        raise ResumeError(f"{where}: the recorded configuration differs from the one its source gives: "
                          f"{', '.join(diff)}")
    check_device(rec, device)


def check_device(rec: RecordedRun, device: dict[str, Any] | None) -> None:
    """Refuse to resume on another firmware (build, model, protocol) than the one that recorded the run."""
    where = f"{rec.path}:1"
    want = rec.header.get("device")
    if isinstance(want, dict) and device is not None:
        diff = [f"{k} {want.get(k)!r} (this device: {device.get(k)!r})" for k in DEVICE_KEYS
                if k in want and want.get(k) != device.get(k)]
        if diff:
            raise ResumeError(f"{where}: recorded with another firmware than this device's: {', '.join(diff)}; "
                              "resume on the same firmware (or start a new run)")


def resume_run(device: Any, rec: RecordedRun, flight: Flight, locked: LockedResults,
               timeout_s: float = DEVICE_TIMEOUT_S,
               progress: Callable[[int, int], None] | None = None) -> tuple[RunResult, dict[str, Any]]:
    """Replay the recorded part, stream the rest, append to the (locked) file. Returns the whole-flight
    RunResult (read back from the file) and what the resume did. A replay that differs from the record
    raises ResumeError before anything is written."""
    cfg, pacing = rec.config(), rec.pacing()
    k0 = rec.next_index
    info: dict[str, Any] = {"resumed_at": k0, "replayed": 0, "replay_mismatches": 0, "appended": 0}
    if rec.complete:
        info["note"] = "nothing to resume: every measurement has a result"
        return run_from_file(rec.path, flight), info
    prefix, suffix = split_flight(flight, k0)
    streamer = Streamer(device, timeout_s=timeout_s)
    t0 = time.perf_counter()
    if prefix is not None:
        window = pacing.window if pacing.mode != "lockstep" else 64
        replay = streamer.run(prefix, cfg, Pacing("windowed", window), results_path=None)
        n_diff, first = replay_differences(replay.results, rec.results_array()[:k0])
        if n_diff:
            raise ResumeError(f"{rec.path}: the replay of the recorded part differs from its records at {n_diff} of "
                              f"{k0} measurements beyond float tolerance (first: {first}): the file was edited or "
                              "another firmware wrote it; file left unchanged")
        info["replayed"] = k0
        info["replay_s"] = round(time.perf_counter() - t0, 3)
    assert suffix is not None
    info["partial_line_bytes_dropped"] = truncate_partial_line(locked.fh, rec.path)
    writer = ResultsWriter(None, None, locked=locked, offset=k0)
    locked.fh.seek(0, 2)
    writer.write_record({"type": REC_RESUME, **info, "segment": rec.segments + 1,
                         "time": time.strftime("%Y-%m-%dT%H:%M:%S")})
    streamer.run(suffix, cfg, pacing, writer=writer, reset=prefix is None, progress=progress)
    info["appended"] = len(suffix.uwb)
    return run_from_file(rec.path, flight), info


def run_from_file(path: Path, flight: Flight) -> RunResult:
    """A RunResult for the whole flight from a (possibly resumed) results file, for run_summary()."""
    rec = read_results(path)
    next_index = rec.next_index
    results = rec.records.results_array(rec.n_measurements, take=True)     # the columns are freed as copied
    stats, decoder = None, DecoderErrors()
    if rec.records.stats is not None:
        obj = rec.records.stats
        stats = m.Stats(**{k: int(obj[k]) for k, _ in m.Stats.FIELDS})
        hd = obj.get("host_decoder", {})
        decoder = DecoderErrors(**{k: int(v) for k, v in hd.items() if k in DecoderErrors.__dataclass_fields__})
    n = len(results)
    sim = (int(flight.uwb.t_us[-1]) - int(flight.uwb.t_us[0])) * 1e-6 if n else 0.0
    pending = int(np.count_nonzero(results["outcome"] == OUTCOME_PENDING))
    if pending and pending != n - next_index:
        raise ResumeError(f"{path}: inconsistent outcomes")
    return RunResult(flight=str(rec.header["flight"]), config=rec.config(), pacing=rec.pacing(), results=results,
                     stats=stats, decoder_errors=decoder, wall_s=0.0, sim_s=sim)
