"""Recorded flights -> `Flight`: `load_recording` picks the reader from the file's content.

    UTIL flight CSV, reduced 8 columns or official 27 columns   harness/flight/formats/util.py
    rcv_twr sequence directory (anchor.yaml, anchor_K.csv, gt.csv)  harness/flight/formats/rcv_twr.py
    native .npz (this project's format)                         harness/flight/native.py
    Crazyflie uSD event log (magic 0xBC, binary)                harness/flight/formats/cf_usd.py (+ _flight.py)
    anchor files (anchors.csv, anchor_constN.npz/.txt, anchor.yaml) harness/flight/formats/anchors.py

Malformed input raises `RecordingError` (a FlightError, so a ValueError) naming the file, the line
and/or field and what was expected; a missing file is FileNotFoundError with the path. What is refused
and what is dropped (and counted in `flight.meta["dropped"]`) is listed in docs/data-formats.md.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from harness.errors import InputError, InputFileNotFound
from harness.options import add_recording_read_options
from harness.flight.formats.anchors import (load_anchor_yaml, load_anchors, load_anchors_csv, load_survey_npz,
                                            load_survey_txt)
from harness.flight.formats.cf_usd import is_cf_usd
from harness.flight.formats.cf_usd_flight import UsdOptions, load_cf_usd
from harness.flight.formats.common import RecordingError, bounded_lines, quote
from harness.flight.formats.rcv_twr import (RANGE_COLUMNS, FROM_DATA_README, GT_COLUMNS, is_rcv_twr_dir,
                                            load_rcv_twr)
from harness.flight.formats.util import constellation_from_name, load_util_csv, util_layout
from harness.flight.data import Anchors, Flight, FlightError
from harness.kinds import kind_of
from harness.flight.native import is_native, load_flight, save_flight
from harness.flight.plausibility import ImplausibleRecording, check_recording

__all__ = ["RecordingError", "ImplausibleRecording", "load_recording", "load_recordings", "recordings_from_args", "load_anchors", "load_anchors_csv", "load_survey_npz",
           "load_survey_txt", "load_anchor_yaml", "load_util_csv", "load_rcv_twr", "load_flight", "save_flight",
           "find_anchor_file", "time_slice", "FROM_DATA_README", "UsdOptions"]

AnchorsArg = Anchors | Path | str | None


def load_recording(path: Path | str, anchors: AnchorsArg = None, *, constellation: int | None = None,
                   anchor_offset: tuple[float, float, float] | str | None = FROM_DATA_README,
                   check: bool = True, usd: UsdOptions = UsdOptions()) -> Flight:
    """Load any supported recording, then check it is plausible (harness/flight/plausibility.py: units,
    anchor geometry, gross errors, time overlap; `ImplausibleRecording` names the file and the likely
    cause). check=False (the CLI's --force) skips that check, never the format checks.

    anchors: an `Anchors`, or an anchor file. UTIL CSVs need one; when None, an `anchors.csv` next to the
        recording or up to two directories above it is used. The constellation of a multi-constellation
        anchors.csv is `constellation`, else the `constN` in the recording's file name.
        For rcv_twr, None means the sequence's anchor.yaml; for a native file, given anchors replace the
        stored ones.
    anchor_offset: rcv_twr only, added to the anchor positions (the source's antenna offset; None = none).
    usd: Crazyflie uSD logs only: --ignore-crc and the tag's lever arm. Their anchors default to the
        `anchor_<day>.npz` (UTIL survey layout) beside the log.
    """
    flight = _load(Path(path), anchors, constellation, anchor_offset, usd)
    if check:
        check_recording(flight, path)
    return flight


def load_recordings(paths: Sequence[Path | str], anchors: AnchorsArg = None, *, check: bool = True,
                    usd: UsdOptions = UsdOptions()) -> list[Flight]:
    """Several recordings read alike (load_recording); the first bad one raises, nothing half-loaded."""
    return [load_recording(p, anchors, check=check, usd=usd) for p in paths]


def recordings_from_args(args: Any, tof: bool = False) -> list[Flight]:
    """The flights of a command's --recording (list), --anchors, --force and add_recording_read_options."""
    usd = UsdOptions.make(args.ignore_crc, args.lever_arm, tof=tof)
    return load_recordings(args.recording, args.anchors or None, check=not args.force, usd=usd)


def _load(path: Path, anchors: AnchorsArg, constellation: int | None,
          anchor_offset: tuple[float, float, float] | str | None, usd: UsdOptions) -> Flight:
    if not path.exists():
        raise InputFileNotFound(f"recording {path} not found")
    if path.is_file() and is_cf_usd(path):
        return load_cf_usd(path, _usd_anchors(anchors, path, constellation), usd)
    if path.is_dir():
        if not is_rcv_twr_dir(path):
            raise RecordingError("this directory is not a recording: expected an rcv_twr sequence (anchor.yaml, "
                                 "anchor_K.csv, gt.csv)", path=path)
        given = _anchors(anchors, path, constellation) if anchors is not None else None
        return load_rcv_twr(path, given, anchor_offset=anchor_offset)
    if path.suffix.lower() == ".npz":
        if not is_native(path):
            hint = (" (this is a UTIL anchor survey: pass it as the anchors)"
                    if _has_members(path, {"an_pos.npy", "an_quat.npy"}) else "")
            raise RecordingError(f"not a native uwb-hil recording{hint}", path=path)
        flight = load_flight(path)
        if anchors is not None:
            flight = replace(flight, anchors=_anchors(anchors, path, constellation))
            try:
                flight.validate()
            except FlightError as exc:
                raise RecordingError(f"with the given anchors: {exc}", path=path) from None
        return flight
    header = _header(path)
    if util_layout(header) is not None:
        return load_util_csv(path, _util_anchors(anchors, path, constellation))
    if set(RANGE_COLUMNS) <= set(header) or set(GT_COLUMNS) <= set(header):
        raise RecordingError("this is one file of an rcv_twr sequence: pass the sequence directory", path=path)
    if "anchor_id" in header:
        raise RecordingError("this is an anchor file: pass it as the anchors, with a recording", path=path)
    raise RecordingError("unknown recording format: expected a UTIL flight CSV (8 or 27 columns), an rcv_twr "
                         f"sequence directory or a native .npz; the header is {quote(','.join(header))}", path=path,
                         line=1)


def time_slice(flight: Flight, start_s: float, end_s: float) -> Flight:
    """The part of a flight between start_s and end_s seconds after its first UWB measurement
    (short test replays, train/evaluation splits). Truth keeps one sample beyond each end so it still
    interpolates over the whole slice."""
    if not end_s > start_s:
        raise InputError(f"time_slice needs end_s > start_s, got {start_s}, {end_s}")
    t0 = int(flight.uwb.t_us[0]) if len(flight.uwb) else 0
    lo, hi = t0 + int(round(start_s * 1e6)), t0 + int(round(end_s * 1e6))
    u = flight.uwb
    m = (u.t_us >= lo) & (u.t_us < hi)
    if not m.any():
        raise InputError(f"{flight.name}: no UWB measurement between {start_s} s and {end_s} s")
    uwb = u.take(m)
    tr = flight.truth
    i0 = max(int(np.searchsorted(tr.t_us, lo, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(tr.t_us, hi, side="left")) + 1, len(tr.t_us))
    truth = replace(tr, t_us=tr.t_us[i0:i1], pos=tr.pos[i0:i1],
                    quat=tr.quat[i0:i1] if tr.quat is not None else None,
                    vel=tr.vel[i0:i1] if tr.vel is not None else None)
    imu = flight.imu
    if imu is not None:
        k = (imu.t_us >= lo) & (imu.t_us < hi)
        imu = replace(imu, t_us=imu.t_us[k], acc=imu.acc[k], gyro=imu.gyro[k])
    aux = flight.aux
    if aux is not None:
        aux = aux.take((aux.t_us >= lo) & (aux.t_us < hi))
    meta = dict(flight.meta, slice_s=[float(start_s), float(end_s)])
    return Flight(name=f"{flight.name}[{start_s:g}-{end_s:g}s]", anchors=flight.anchors, uwb=uwb, truth=truth,
                  imu=imu, meta=meta, aux=aux)


def find_anchor_file(recording: Path) -> Path | None:
    """An `anchors.csv` in the recording's directory or up to two levels above it."""
    here = recording.resolve().parent
    for d in (here, here.parent, here.parent.parent):
        if (d / "anchors.csv").is_file():
            return d / "anchors.csv"
    return None


def find_usd_anchor_file(recording: Path) -> Path | None:
    """The `anchor_<day>.npz` beside a uSD log (day = the file name's part before '-'), else the only
    `anchor_*.npz` there."""
    here = recording.resolve().parent
    day = recording.name.split("-")[0]
    if (here / f"anchor_{day}.npz").is_file():
        return here / f"anchor_{day}.npz"
    found = sorted(here.glob("anchor_*.npz"))
    return found[0] if len(found) == 1 else None


def _usd_anchors(anchors: AnchorsArg, path: Path, constellation: int | None) -> Anchors:
    if anchors is None:
        found = find_usd_anchor_file(path)
        if found is None:
            raise RecordingError("no anchors given and no anchor_<day>.npz beside this Crazyflie uSD log: pass "
                                 "--anchors (a UTIL survey .npz with an_pos/an_quat, or anchors.csv)", path=path)
        anchors = found
    return _anchors(anchors, path, constellation)


def _util_anchors(anchors: AnchorsArg, path: Path, constellation: int | None) -> Anchors:
    if anchors is None:
        found = find_anchor_file(path)
        if found is None:
            raise RecordingError("no anchors given and no anchors.csv found next to the recording: pass the "
                                 "anchor file (--anchors anchors.csv or a UTIL survey anchor_constN.npz/.txt)",
                                 path=path)
        anchors = found
    return _anchors(anchors, path, constellation)


def _anchors(anchors: AnchorsArg, recording: Path, constellation: int | None) -> Anchors:
    if isinstance(anchors, Anchors):
        return anchors
    assert anchors is not None
    return load_anchors(Path(anchors), constellation if constellation is not None
                        else constellation_from_name(recording))


def _header(path: Path) -> tuple[str, ...]:
    """The first non-blank line of a text file, split on commas (cheap: the dispatch reads nothing else)."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            for line in bounded_lines(f, path):
                if line.strip():
                    return tuple(c.strip() for c in line.rstrip("\r\n").split(","))
    except UnicodeDecodeError:
        raise RecordingError("not a text file: expected a CSV recording (or a .npz / directory)", path=path) from None
    raise RecordingError("empty file, expected a recording with a header line", path=path, line=1)


def _has_members(path: Path, names: set[str]) -> bool:
    import zipfile
    try:
        with zipfile.ZipFile(path) as z:
            return names <= set(z.namelist())
    except (zipfile.BadZipFile, OSError):
        return False



# ------------------------------------------------------------------------------------------ command line
def error_summary(flight: Flight, core_m: float = 1.0) -> dict[str, object]:
    """Measurement error (value - true_value) statistics: overall and per anchor (TWR) or pair (TDoA).

    `core` statistics use |error| < core_m (gross outliers are counted, not averaged)."""
    u = flight.uwb
    if u.true_value is None:
        raise InputError(f"{flight.name}: no true_value, no error statistics")
    e = u.value - u.true_value
    kind = kind_of(u.kind)
    keys = kind.link_keys(u.anchor_a, u.anchor_b)
    groups = []
    for k in np.unique(keys):
        m = keys == k
        c = e[m][np.abs(e[m]) < core_m]
        name = str(int(k)) if kind.n_anchors == 1 else f"{int(k) // 1000}-{int(k) % 1000}"
        groups.append({"group": name, "n": int(m.sum()), "median": float(np.median(c)) if c.size else float("nan"),
                       "std": float(c.std()) if c.size else float("nan"),
                       "gross": int(np.count_nonzero(np.abs(e[m]) >= core_m))})
    core = e[np.abs(e) < core_m]
    medians = np.array([g["median"] for g in groups if g["n"] >= 20], dtype=np.float64)
    stds = np.array([g["std"] for g in groups if g["n"] >= 20], dtype=np.float64)
    return {"n": int(e.size), "gross": int(e.size - core.size), "median": float(np.median(core)),
            "std": float(core.std()), "rms": float(np.sqrt(np.mean(core ** 2))),
            "group_median_spread": float(medians.std()) if medians.size else float("nan"),
            "group_median_min": float(medians.min()) if medians.size else float("nan"),
            "group_median_max": float(medians.max()) if medians.size else float("nan"),
            "within_group_std_median": float(np.median(stds)) if stds.size else float("nan"),
            "groups": groups}


def main(argv: list[str] | None = None) -> int:
    """`python -m harness.flight.loaders RECORDING [--anchors FILE] [--save OUT.npz]`: load, summarise the
    measurement errors against the truth, optionally convert to the native format."""
    import argparse
    import sys
    ap = argparse.ArgumentParser(prog="python -m harness.flight.loaders", description=main.__doc__)
    ap.add_argument("recording", help="UTIL CSV, rcv_twr sequence directory, Crazyflie uSD log or native .npz")
    ap.add_argument("--anchors", help="anchor file (UTIL anchors.csv, survey .npz/.txt, anchor.yaml)")
    ap.add_argument("--constellation", type=int, help="constellation N of a multi-constellation anchors.csv")
    ap.add_argument("--no-anchor-offset", action="store_true", help="rcv_twr: use the surveyed anchor positions")
    ap.add_argument("--save", help="write the flight in the native format (.npz)")
    ap.add_argument("--force", action="store_true", help="load an implausible recording anyway (units, geometry)")
    add_recording_read_options(ap)
    args = ap.parse_args(argv)
    try:
        flight = load_recording(args.recording, args.anchors, constellation=args.constellation,
                                anchor_offset=None if args.no_anchor_offset else FROM_DATA_README,
                                check=not args.force, usd=UsdOptions.make(args.ignore_crc, args.lever_arm))
    except (RecordingError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    kind = kind_of(flight.uwb.kind)
    print(f"{flight.name}: {len(flight.uwb)} {kind.label} measurements over {flight.duration_s:.1f} s "
          f"({len(flight.uwb) / max(flight.duration_s, 1e-9):.0f} Hz), {len(flight.truth.t_us)} truth samples, "
          f"IMU {len(flight.imu) if flight.imu is not None else 0}; dropped {flight.meta.get('dropped', {})}")
    from harness.flight.plausibility import figures
    fig = figures(flight)
    print("plausibility: anchors span {anchor_spread_m:.2f} m (closest pair {anchor_min_separation_m:.2f} m, "
          "{off_line_mm:.0f} mm rms off a line), poses a median {pose_median_distance_m:.2f} m from the anchors' "
          "centre, {rate_hz:.1f} Hz, median |value| {median_abs_value_m:.2f} m, gross errors {gross:.2f} %"
          .format(**fig, off_line_mm=1000 * fig["anchor_off_line_m"], gross=100 * fig.get("gross_share", float("nan")))
          + (f"; IMU median |specific force| {fig['acc_median_mps2']:.2f} m/s^2, p99 |body rate| "
             f"{fig['gyro_p99_rads']:.2f} rad/s" if "acc_median_mps2" in fig else ""))
    s = error_summary(flight)
    print(f"error (|e| < 1 m): median {s['median']:+.3f} m, std {s['std']:.3f} m, rms {s['rms']:.3f} m; "
          f"gross {s['gross']}; per-{kind.link} medians {s['group_median_min']:+.3f}"
          f"..{s['group_median_max']:+.3f} m (spread {s['group_median_spread']:.3f}), within std "
          f"{s['within_group_std_median']:.3f} m")
    for g in s["groups"]:  # type: ignore[attr-defined]
        print(f"  {g['group']:>6}: n {g['n']:6d}  median {g['median']:+.3f}  std {g['std']:.3f}  gross {g['gross']}")
    if args.save:
        print(f"saved {save_flight(flight, Path(args.save))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
