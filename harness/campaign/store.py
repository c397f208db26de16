"""The on-disk layout of a campaign directory (written by the runner, read by the report).

    DIR/campaign.json            options, the planned runs, notes, provenance of the host side
    DIR/runs/<run_id>.jsonl      per-measurement results, streamed as they arrive (Streamer results_path);
                                 removed when the run completes (--keep-jsonl: kept as <run_id>.jsonl.gz)
    DIR/runs/<run_id>.npy        the same rows in binary (streamer RESULTS_DTYPE), written when the run completes:
                                 the report reads it (parsing a full campaign's JSONL takes minutes)
    DIR/models/                  the networks the campaign ran (harness/campaign/models.py)
    DIR/runs/<run_id>.json       small per-run summary; "status" is "ok" or "failed" (written last, atomically)
    DIR/flights/<flight_id>.npz  what the report needs of the flight: truth, measurements, anchors
    DIR/logs/                    device logs and worker output
    DIR/verdict.json             the campaign's verdict (harness/campaign/verdict.py): each judged run's checks

A run is complete when its summary says "ok" and carries the fingerprint of the current RunSpec.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from harness.errors import InputError
from harness.flight.data import Flight
from harness.kinds import kind_of
from harness.stream.results_file import COLUMNS, column_dtype, read_run

STATUS_OK = "ok"
STATUS_FAILED = "failed"
VERDICT_FILE = "verdict.json"


class CampaignDataError(InputError):
    """A file of a campaign directory is missing or malformed (names the file, line and field)."""


@dataclass(frozen=True)
class CampaignDir:
    root: Path

    @property
    def manifest(self) -> Path:
        return self.root / "campaign.json"

    @property
    def runs(self) -> Path:
        return self.root / "runs"

    @property
    def flights(self) -> Path:
        return self.root / "flights"

    @property
    def logs(self) -> Path:
        return self.root / "logs"

    def results_path(self, run_id: str) -> Path:
        return self.runs / f"{run_id}.jsonl"

    def results_gz_path(self, run_id: str) -> Path:
        return self.runs / f"{run_id}.jsonl.gz"

    def finish_results(self, run_id: str, keep_jsonl: bool) -> None:
        """A complete run keeps its binary rows; its JSON Lines (6x larger) are dropped or gzip-compressed."""
        src = self.results_path(run_id)
        if keep_jsonl and src.exists():
            tmp = self.runs / f".{run_id}.{os.getpid()}.tmp.gz"
            with open(src, "rb") as fin, gzip.open(tmp, "wb", compresslevel=6) as fout:
                shutil.copyfileobj(fin, fout, 1 << 20)
            os.replace(tmp, self.results_gz_path(run_id))
        src.unlink(missing_ok=True)

    def array_path(self, run_id: str) -> Path:
        return self.runs / f"{run_id}.npy"

    @property
    def verdict(self) -> Path:
        return self.root / VERDICT_FILE

    def summary_path(self, run_id: str) -> Path:
        return self.runs / f"{run_id}.json"

    def flight_path(self, flight_id: str) -> Path:
        return self.flights / f"{flight_id}.npz"

    def make(self) -> None:
        for d in (self.root, self.runs, self.flights, self.logs):
            d.mkdir(parents=True, exist_ok=True)

    def read_summary(self, run_id: str) -> dict[str, Any] | None:
        """The run's summary, or None if it has none (never run, or interrupted before the end)."""
        path = self.summary_path(run_id)
        if not path.exists():
            return None
        return read_json(path)

    def is_complete(self, run_id: str, fingerprint: str, firmware_sha256: str | None = None) -> bool:
        """Done with this RunSpec and (if given) this very firmware binary: a rebuilt firmware (new model,
        new code) at the same path must not be mixed with results of the old one."""
        try:
            s = self.read_summary(run_id)
        except CampaignDataError:
            return False      # a torn summary (should not happen: writes are atomic) means: run again
        return bool(s and s.get("status") == STATUS_OK and s.get("fingerprint") == fingerprint
                    and (firmware_sha256 is None or s.get("firmware_sha256") == firmware_sha256)
                    and (self.array_path(run_id).exists() or self.results_path(run_id).exists()))

    def flight_file_ok(self, flight_id: str) -> bool:
        """The stored flight reads as the report reads it (load_flight): a flight whose file was deleted or
        damaged is flown again on resume, which writes it anew."""
        try:
            load_flight(self.flight_path(flight_id))
        except CampaignDataError:
            return False
        return True


def write_json_atomic(path: Path, obj: Any) -> None:
    """Write to a temporary file and rename it over the target: readers never see half a file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=1, default=_json_default, allow_nan=True)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def save_array_atomic(path: Path, arr: np.ndarray) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npy")
    np.save(tmp, arr, allow_pickle=False)
    os.replace(tmp, path)


def read_json(path: Path) -> Any:
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise CampaignDataError(f"{path}: line {exc.lineno}: malformed JSON ({exc.msg})") from None
    except UnicodeDecodeError as exc:      # a JSONDecodeError is a ValueError too: after it
        raise CampaignDataError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise CampaignDataError(f"{path}: cannot read ({exc.strerror})") from None


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, bytes):
        return o.decode(errors="replace")
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


# ------------------------------------------------------------------------------------------ flights
def geometric_values(flight: Flight) -> np.ndarray:
    """Noise-free measurement values from the true tag position (the reference for 'measured error')."""
    u = flight.uwb
    p = flight.truth.position_at(u.t_us.astype(np.int64))
    ids = flight.anchors.ids.astype(np.int64)
    order = np.argsort(ids)
    pos = flight.anchors.positions[order]
    a = pos[np.searchsorted(ids[order], u.anchor_a.astype(np.int64))]
    da = np.linalg.norm(p - a, axis=1)
    if kind_of(u.kind).n_anchors == 2:
        b = pos[np.searchsorted(ids[order], u.anchor_b.astype(np.int64))]
        return np.linalg.norm(p - b, axis=1) - da
    return da


def save_flight(path: Path, flight: Flight, meta: dict[str, Any]) -> None:
    u = flight.uwb
    true_value = u.true_value if u.true_value is not None else geometric_values(flight)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(
        tmp, truth_t_us=flight.truth.t_us.astype(np.int64), truth_pos=flight.truth.pos.astype(np.float64),
        uwb_kind=np.int64(u.kind), uwb_t_us=u.t_us.astype(np.int64), uwb_anchor_a=u.anchor_a.astype(np.int64),
        uwb_anchor_b=u.anchor_b.astype(np.int64), uwb_value=u.value.astype(np.float64),
        uwb_true_value=np.asarray(true_value, dtype=np.float64),
        anchor_ids=flight.anchors.ids.astype(np.int64), anchor_pos=flight.anchors.positions.astype(np.float64),
        meta=np.array(json.dumps(meta, default=_json_default)))
    os.replace(tmp, path)


@dataclass(frozen=True)
class StoredFlight:
    flight_id: str
    truth_t_us: np.ndarray
    truth_pos: np.ndarray
    kind: int
    uwb_t_us: np.ndarray
    anchor_a: np.ndarray
    anchor_b: np.ndarray
    value: np.ndarray
    true_value: np.ndarray
    anchor_ids: np.ndarray
    anchor_pos: np.ndarray
    meta: dict[str, Any]

    def position_at(self, t_us: np.ndarray) -> np.ndarray:
        """Linear interpolation of the true tag position (same rule as harness.flight.data.Truth)."""
        t = np.asarray(t_us, dtype=np.float64)
        tt = self.truth_t_us.astype(np.float64)
        return np.stack([np.interp(t, tt, self.truth_pos[:, k]) for k in range(3)], axis=-1)


def load_flight(path: Path) -> StoredFlight:
    names = ("truth_t_us", "truth_pos", "uwb_kind", "uwb_t_us", "uwb_anchor_a", "uwb_anchor_b", "uwb_value",
             "uwb_true_value", "anchor_ids", "anchor_pos", "meta")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [n for n in names if n not in z.files]
            if missing:
                raise CampaignDataError(f"{path}: missing field(s) {missing}")
            d = {n: z[n] for n in names}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:   # a cut or flipped .npz
        if isinstance(exc, CampaignDataError):
            raise
        raise CampaignDataError(f"{path}: not a readable flight file ({exc})") from None
    return StoredFlight(flight_id=path.stem, truth_t_us=d["truth_t_us"], truth_pos=d["truth_pos"],
                        kind=int(d["uwb_kind"]), uwb_t_us=d["uwb_t_us"], anchor_a=d["uwb_anchor_a"],
                        anchor_b=d["uwb_anchor_b"], value=d["uwb_value"], true_value=d["uwb_true_value"],
                        anchor_ids=d["anchor_ids"], anchor_pos=d["anchor_pos"], meta=json.loads(str(d["meta"])))


# ------------------------------------------------------------------------------------------ results
#: The columns of a results file (harness/stream/results_file.py) that the report reads.
RESULT_COLUMNS = ("index", "kind", "status", "t_us", "innovation", "innovation_var", "bias", "d_max",
                  "compute", "cost_nn", "cost_gates", "cost_update", "px", "py", "pz", "var_x", "var_y",
                  "var_z", "t_send_ns", "t_recv_ns", "outcome", "error_code")
assert set(RESULT_COLUMNS) <= set(COLUMNS)


@dataclass(frozen=True)
class StoredResults:
    header: dict[str, Any]
    columns: dict[str, np.ndarray]     # RESULT_COLUMNS -> (M,) arrays, row k = measurement index k
    stats: dict[str, Any] | None       # the trailing "stats" record (device counters), if the run finished
    records: tuple[dict[str, Any], ...] = ()   # other records, e.g. "device_error" (DIVERGED, refused IMU)

    def __len__(self) -> int:
        return int(len(self.columns["index"]))


def load_results(path: Path) -> StoredResults:
    """Parse one run's results file (results_file.read_run). Every malformed line is an error naming the
    file, line and field."""
    try:
        run = read_run(path, CampaignDataError, columns=RESULT_COLUMNS)
    except FileNotFoundError as exc:
        raise CampaignDataError(str(exc)) from None
    return StoredResults(header=run.header, columns=run.columns, stats=run.stats, records=tuple(run.records))


def load_run_results(cdir: CampaignDir, run_id: str, stats: dict[str, Any] | None = None) -> StoredResults:
    """A complete run's rows: from the binary copy when it is there and well formed, else from the JSONL."""
    npy = cdir.array_path(run_id)
    if npy.exists():
        try:
            arr = np.load(npy, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise CampaignDataError(f"{npy}: not a readable results array ({exc})") from None
        names = arr.dtype.names or ()
        missing = [c for c in RESULT_COLUMNS if c != "index" and c not in names]
        if missing:
            raise CampaignDataError(f"{npy}: missing field(s) {missing}")
        cols: dict[str, np.ndarray] = {"index": np.arange(len(arr), dtype=np.int64)}
        for c in RESULT_COLUMNS[1:]:
            cols[c] = arr[c].astype(column_dtype(c))
        return StoredResults(header={"type": "header", "source": str(npy)}, columns=cols, stats=stats)
    gz = cdir.results_gz_path(run_id)
    return load_results(gz if gz.exists() else cdir.results_path(run_id))
