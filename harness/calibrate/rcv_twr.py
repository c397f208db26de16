"""rcv_twr TWR: every recorded range with its geometry, the simulator's error at the same poses, and the
error's dependence on the relative pose."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from harness.calibrate.stats import CalibrationError, error_stats, trial_summary
from harness.flight.arena import Arena
from harness.flight.data import KIND_TWR, Anchors
from harness.flight.formats.rcv_twr import ORIENTATION_COLUMNS, POSITION_COLUMNS, RANGE_COLUMNS, readme_anchor_offset
from harness.flight.measurement_errors import SimConfig, azimuth_elevation, link_directions, sim_config, uwb_errors



@dataclass(frozen=True)
class TwrLinks:
    """Every rcv_twr range with its geometry, and the simulator's error at the same poses."""

    sequence: np.ndarray
    anchor: np.ndarray
    err_real: np.ndarray
    err_sim: np.ndarray
    az_anchor: np.ndarray    # tag seen from the anchor (anchor frame) [rad]
    el_anchor: np.ndarray
    az_tag: np.ndarray       # anchor seen from the tag (body frame) [rad]
    el_tag: np.ndarray
    rng: np.ndarray


def read_rcv_ranges(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """rcv_twr anchor_K.csv -> (t_s, range, tag pos (N, 3), tag quat (N, 4) w, x, y, z). The columns are
    the loader's (formats/rcv_twr.py RANGE_COLUMNS), looked up by name in the file's header."""
    numeric = ("Range", *POSITION_COLUMNS, *ORIENTATION_COLUMNS)
    if not path.is_file():
        raise CalibrationError(f"{path}: file not found")
    t, vals = [], []
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        if not set(RANGE_COLUMNS) <= set(header):
            raise CalibrationError(f"{path}:1: expected header with {','.join(RANGE_COLUMNS)}, got {header!r}")
        col = {name: header.index(name) for name in RANGE_COLUMNS}
        for lineno, row in enumerate(reader, start=2):
            if len(row) != len(header):
                raise CalibrationError(f"{path}:{lineno}: expected {len(header)} fields, got {len(row)}")
            try:
                t.append(datetime.fromisoformat(row[col["Time"]]).timestamp())
            except ValueError:
                raise CalibrationError(f"{path}:{lineno}: field Time is not a date-time: {row[col['Time']]!r}"
                                       ) from None
            try:
                vals.append([float(row[col[c]]) for c in numeric])
            except ValueError:
                raise CalibrationError(f"{path}:{lineno}: a numeric field is not a number: "
                                       f"{[row[col[c]] for c in numeric]}") from None
    if not vals:
        raise CalibrationError(f"{path}: no ranges")
    a = np.array(vals)
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{path}: non-finite values")
    q = a[:, [7, 4, 5, 6]]
    return np.array(t), a[:, 0], a[:, 1:4], q / np.linalg.norm(q, axis=1, keepdims=True)


def rcv_twr_links(data_dir: Path, config: SimConfig | None = None, seed: int = 7) -> TwrLinks:
    from harness.flight.formats.anchors import load_anchors
    root = data_dir / "rcv_twr"
    seqs = sorted(p for p in root.glob("sequence*") if p.is_dir())
    if not seqs:
        raise CalibrationError(f"no rcv_twr sequences under {root}")
    cfg = config or sim_config("los")
    rng = np.random.default_rng(seed)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in TwrLinks.__dataclass_fields__}
    for seq in seqs:
        anchors = load_anchors(seq / "anchor.yaml")
        if anchors.orientations is None:
            raise CalibrationError(f"{seq / 'anchor.yaml'}: anchors have no orientation")
        moved = Anchors(ids=anchors.ids, positions=anchors.positions + readme_anchor_offset(seq),
                        orientations=anchors.orientations)
        arena = Arena(anchors=moved)
        for k, aid in enumerate(moved.ids):
            _, rng_m, pos, quat = read_rcv_ranges(seq / f"anchor_{int(aid)}.csv")
            n = rng_m.size
            ap = np.repeat(moved.positions[k][None, :], n, axis=0)
            aq = np.repeat(moved.orientations[k][None, :], n, axis=0)
            u_a, u_t, r = link_directions(ap, aq, pos, quat)
            ids = np.full(n, int(aid))
            sim = uwb_errors(cfg, KIND_TWR, arena, pos, quat, ids, np.full(n, -1), rng)
            az_a, el_a = azimuth_elevation(u_a)
            az_t, el_t = azimuth_elevation(u_t)
            seq_no = int("".join(ch for ch in seq.name if ch.isdigit()) or 0)
            for name, v in (("sequence", np.full(n, seq_no)), ("anchor", ids), ("err_real", rng_m - r),
                            ("err_sim", sim.total), ("az_anchor", az_a), ("el_anchor", el_a), ("az_tag", az_t),
                            ("el_tag", el_t), ("rng", r)):
                cols[name].append(v)
    return TwrLinks(**{k: np.concatenate(v) for k, v in cols.items()})


ANGLE_BINS = {"az_anchor": np.arange(-180, 181, 30), "el_anchor": np.arange(-60, 61, 15),
              "az_tag": np.arange(-180, 181, 30), "el_tag": np.arange(-60, 61, 15)}


def centered(links: TwrLinks, err: np.ndarray) -> np.ndarray:
    """Error minus its own link's median (sequence x anchor): the pose-dependent part."""
    out = np.empty_like(err)
    for key in set(zip(links.sequence.tolist(), links.anchor.tolist())):
        m = (links.sequence == key[0]) & (links.anchor == key[1])
        out[m] = err[m] - np.median(err[m])
    return out


def twr_dependence(links: TwrLinks, clip: float = 1.0) -> dict[str, Any]:
    """Binned medians of the centred error against each angle, real and simulated, and the overall
    amplitude of the pose dependence (std of the binned medians, weighted by bin counts)."""
    out: dict[str, Any] = {}
    for key, edges in ANGLE_BINS.items():
        ang = np.degrees(getattr(links, key))
        rows = []
        amp = {}
        for label, err in (("real", links.err_real), ("sim", links.err_sim)):
            c = centered(links, err)
            ok = np.abs(c) < clip
            idx = np.digitize(ang, edges) - 1
            meds, counts = [], []
            for i in range(len(edges) - 1):
                m = ok & (idx == i)
                meds.append(float(np.median(c[m])) if m.sum() >= 20 else math.nan)
                counts.append(int(m.sum()))
            rows.append((label, meds, counts))
            mv, cv = np.array(meds), np.array(counts, dtype=float)
            good = np.isfinite(mv)
            amp[label] = float(np.sqrt(np.average((mv[good] - np.average(mv[good], weights=cv[good])) ** 2,
                                                  weights=cv[good]))) if good.sum() > 1 else math.nan
        out[key] = {"edges_deg": edges.tolist(), "real_median": rows[0][1], "sim_median": rows[1][1],
                    "counts": rows[0][2], "amplitude": amp}
    return out


def twr_stats(links: TwrLinks) -> dict[str, dict[str, float]]:
    res = {}
    for label, err in (("real", links.err_real), ("sim", links.err_sim)):
        trials = []
        for s in np.unique(links.sequence):
            m = links.sequence == s
            trials.append(error_stats(err[m], links.anchor[m]))
        res[label] = {k: v["mean"] for k, v in trial_summary(trials).items()}
        c = centered(links, err)
        res[label]["centred_std"] = float(c[np.abs(c) < 1.0].std())
    return res
