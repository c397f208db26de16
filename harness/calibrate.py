"""`uwb-hil calibrate`: the simulator's measurement errors next to the real recordings in ../shared/data.

Real error = measured - geometric truth (UTIL: the tag 0.0908 m above the Vicon pose; rcv_twr: anchors
moved by the source's antenna offset (0, -0.05, +0.045) m). Statistics are per trial (one flight file or
one simulated flight) and then averaged over trials, so no single file decides a number:

* UTIL TDoA groups: LOS TDoA2 (const1 + const2), LOS TDoA3 (const1), NLOS TDoA2 (const3). The simulated
  side flies the same constellations (antennas facing the centroid; UTIL has no orientations) on
  `random` campaign flights with take-off and landing at the real rates, profile "los" or "nlos".
  Per trial: mean, median, std (|e| < 1 m, as the data README measures), tail fractions |e| > 0.3 m and
  > 1 m (all samples), and the per-pair bias spread = std over anchor pairs of the pair's mean error
  (|e| < 1 m; pairs with >= 1 % of the trial's samples; a pair and its reverse are one pair).
* rcv_twr TWR: the simulator's error model evaluated at the recorded poses (same anchors and antenna
  orientations), and the error's dependence on azimuth/elevation of the tag seen from the anchor and of
  the anchor seen from the tag (binned medians, each link's median removed: the pose-dependent part).
"""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from harness.flight.arena import Arena, with_facing_orientations
from harness.flight.measurement_errors import SimConfig, azimuth_elevation, link_directions, sim_config, uwb_errors
from harness.flight.data import KIND_TWR, Anchors, FlightError
from harness.report import jsonsafe
from harness.session import shared_data_dir

RCV_ANCHOR_OFFSET = np.array([0.0, -0.05, 0.045])   # data README: the source's antenna offset
MIN_PAIR_SHARE = 0.01
STATS_KEYS = ("n", "mean", "median", "std", "frac_gt_0.3", "frac_gt_1", "pair_spread", "noise")


class CalibrationError(FlightError):
    """Real data missing or unreadable for calibration (names the file)."""


# ------------------------------------------------------------------------------------------ stats
@dataclass(frozen=True)
class ErrorStats:
    n: int
    mean: float
    median: float
    std: float
    frac_gt_03: float
    frac_gt_1: float
    pair_spread: float
    noise: float
    pair_means: dict[str, float] = field(default_factory=dict)

    def row(self) -> dict[str, float]:
        return {"n": self.n, "mean": self.mean, "median": self.median, "std": self.std,
                "frac_gt_0.3": self.frac_gt_03, "frac_gt_1": self.frac_gt_1, "pair_spread": self.pair_spread,
                "noise": self.noise}


def error_stats(err: np.ndarray, a: np.ndarray, b: np.ndarray | None = None, clip: float = 1.0) -> ErrorStats:
    """Statistics of one trial's errors (time-ordered). TDoA pairs are canonical (low id first, error sign
    flipped for the reverse pair); for TWR (b None) the "pairs" are the anchors. `noise` estimates the
    white part from successive differences within a pair (the bias varies slowly between them)."""
    err = np.asarray(err, dtype=np.float64)
    if err.size == 0:
        raise CalibrationError("no measurements to compute statistics on")
    if b is None or np.all(b < 0):
        lo, hi, e_c = a, np.full_like(a, -1), err
    else:
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        e_c = np.where(a < b, err, -err)
    ok = np.abs(err) < clip
    pair_means: dict[str, float] = {}
    keys = np.stack([lo, hi], axis=1)
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    for k, (pa, pb) in enumerate(uniq):
        m = (inv == k) & ok
        if counts[k] >= MIN_PAIR_SHARE * err.size and m.sum() > 0:
            pair_means[f"{int(pa)}-{int(pb)}" if pb >= 0 else f"{int(pa)}"] = float(e_c[m].mean())
    pm = np.array(list(pair_means.values()))
    # White-noise part: successive differences within a pair (time-ordered), |d| < 0.5 m, std / sqrt(2).
    diffs = [np.diff(e_c[inv == k]) for k in range(len(uniq))]
    d = np.concatenate(diffs) if diffs else np.zeros(0)
    d = d[np.abs(d) < 0.5]
    return ErrorStats(noise=float(d.std() / np.sqrt(2.0)) if d.size > 1 else math.nan,
                      n=int(err.size), mean=float(err[ok].mean()) if ok.any() else math.nan,
                      median=float(np.median(err)), std=float(err[ok].std()) if ok.any() else math.nan,
                      frac_gt_03=float(np.mean(np.abs(err) > 0.3)), frac_gt_1=float(np.mean(np.abs(err) > 1.0)),
                      pair_spread=float(pm.std()) if pm.size > 1 else math.nan, pair_means=pair_means)


def trial_summary(trials: Sequence[ErrorStats]) -> dict[str, dict[str, float]]:
    """Per statistic: mean over trials, min and max."""
    out: dict[str, dict[str, float]] = {}
    for key in STATS_KEYS:
        v = np.array([t.row()[key] for t in trials], dtype=np.float64)
        out[key] = {"mean": float(np.nanmean(v)), "min": float(np.nanmin(v)), "max": float(np.nanmax(v))}
    return out


# --------------------------------------------------------------------------------------- UTIL TDoA
@dataclass(frozen=True)
class UtilGroup:
    name: str
    pattern: str          # glob under util/
    mode: str             # tdoa2 | tdoa3
    profile: str
    rate_hz: float


UTIL_GROUPS = (
    UtilGroup("LOS TDoA2 (const1+const2)", "const[12]/*-tdoa2-*.csv", "tdoa2", "los", 475.0),
    UtilGroup("LOS TDoA3 (const1)", "const1/*-tdoa3-*.csv", "tdoa3", "los", 280.0),
    UtilGroup("NLOS TDoA2 (const3)", "const3/*-tdoa2-*.csv", "tdoa2", "nlos", 450.0),
)


def _constellation_of(path: Path) -> int:
    name = path.name
    if not name.startswith("const") or not name[5:6].isdigit():
        raise CalibrationError(f"{path}: cannot tell the constellation from the file name (constN-...)")
    return int(name[5])


def util_anchors(data_dir: Path, constellation: int) -> Anchors:
    from harness.flight.formats.anchors import load_anchors
    return load_anchors(data_dir / "util" / "anchors.csv", constellation)


def real_util_trials(data_dir: Path, group: UtilGroup) -> tuple[list[str], list[ErrorStats]]:
    from harness.flight.formats.util import load_util_csv
    files = sorted((data_dir / "util").glob(group.pattern))
    if not files:
        raise CalibrationError(f"no UTIL files {group.pattern} under {data_dir / 'util'}")
    stats = []
    for f in files:
        flight = load_util_csv(f, util_anchors(data_dir, _constellation_of(f)))
        u = flight.uwb
        assert u.true_value is not None
        stats.append(error_stats(u.value - u.true_value, u.anchor_a, u.anchor_b))
    return [f.name for f in files], stats


def sim_util_trials(data_dir: Path, group: UtilGroup, n_trials: int, duration_s: float,
                    config: SimConfig | None = None) -> tuple[list[str], list[ErrorStats]]:
    """Simulated campaign flights in the group's constellations (trial k flies constellation k mod n)."""
    from harness.flight.scenarios import scenario_flight
    consts = sorted({_constellation_of(f) for f in (data_dir / "util").glob(group.pattern)})
    if not consts:
        raise CalibrationError(f"no UTIL files {group.pattern} under {data_dir / 'util'}")
    cfg = config or sim_config(group.profile)
    names, stats = [], []
    for k in range(n_trials):
        c = consts[k % len(consts)]
        raw = util_anchors(data_dir, c)
        anchors = with_facing_orientations(raw, raw.positions.mean(axis=0))
        flight = scenario_flight("random", mode=group.mode, duration_s=duration_s, seed=1000 + k, noise="realistic",
                                 config=cfg, anchors=anchors, rate_hz=group.rate_hz, takeoff=True)
        u = flight.uwb
        assert u.true_value is not None
        stats.append(error_stats(u.value - u.true_value, u.anchor_a, u.anchor_b))
        names.append(f"sim const{c} random seed {1000 + k}")
    return names, stats


# ---------------------------------------------------------------------------------------- rcv TWR
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
    """rcv_twr anchor_K.csv -> (t_s, range, tag pos (N, 3), tag quat (N, 4) w, x, y, z)."""
    want = ["Time", "Address", "Range", "Rxpower", "Position X", "Position Y", "Position Z",
            "Orientation X", "Orientation Y", "Orientation Z", "Orientation W"]
    if not path.is_file():
        raise CalibrationError(f"{path}: file not found")
    t, vals = [], []
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None or [h.strip() for h in header] != want:
            raise CalibrationError(f"{path}:1: expected header {','.join(want)}, got {header!r}")
        for lineno, row in enumerate(reader, start=2):
            if len(row) != len(want):
                raise CalibrationError(f"{path}:{lineno}: expected {len(want)} fields, got {len(row)}")
            try:
                t.append(datetime.fromisoformat(row[0]).timestamp())
            except ValueError:
                raise CalibrationError(f"{path}:{lineno}: field Time is not a date-time: {row[0]!r}") from None
            try:
                vals.append([float(x) for x in row[2:]])
            except ValueError:
                raise CalibrationError(f"{path}:{lineno}: a numeric field is not a number: {row[2:]}") from None
    if not vals:
        raise CalibrationError(f"{path}: no ranges")
    a = np.array(vals)
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{path}: non-finite values")
    q = a[:, [8, 5, 6, 7]]
    return np.array(t), a[:, 0], a[:, 2:5], q / np.linalg.norm(q, axis=1, keepdims=True)


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
        moved = Anchors(ids=anchors.ids, positions=anchors.positions + RCV_ANCHOR_OFFSET,
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


def _centered(links: TwrLinks, err: np.ndarray) -> np.ndarray:
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
            c = _centered(links, err)
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
        c = _centered(links, err)
        res[label]["centred_std"] = float(c[np.abs(c) < 1.0].std())
    return res


# ------------------------------------------------------------------------------------------- plots
def write_plots(out: Path, links: TwrLinks | None, dependence: dict[str, Any] | None,
                util: list[dict[str, Any]]) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    if links is not None and dependence is not None:
        fig, axes = plt.subplots(2, 2, figsize=(11, 8))
        for ax, key in zip(axes.ravel(), ANGLE_BINS):
            d = dependence[key]
            edges = np.array(d["edges_deg"], dtype=float)
            mid = 0.5 * (edges[1:] + edges[:-1])
            c = _centered(links, links.err_real)
            ok = np.abs(c) < 1.0
            ax.scatter(np.degrees(getattr(links, key))[ok], c[ok], s=2, alpha=0.15, color="0.5", label="real (centred)")
            ax.plot(mid, d["real_median"], "o-", color="C0", label="real binned median")
            ax.plot(mid, d["sim_median"], "s--", color="C3", label="simulator binned median")
            ax.set_xlabel(key.replace("_", " ") + " [deg]")
            ax.set_ylabel("range error - link median [m]")
            ax.set_ylim(-0.6, 0.6)
            ax.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=8)
        fig.suptitle("rcv_twr TWR error vs relative pose: real vs simulator (same poses)")
        fig.tight_layout()
        p = out / "twr_error_vs_angle.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    if util:
        fig, axes = plt.subplots(1, len(util), figsize=(5 * len(util), 4), squeeze=False)
        for ax, g in zip(axes[0], util):
            for label, color in (("real", "C0"), ("sim", "C3")):
                pm = [v for t in g[f"{label}_trial_stats"] for v in t["pair_means"].values()]
                ax.hist(pm, bins=np.linspace(-0.3, 0.3, 25), alpha=0.5, color=color, label=f"{label} per-pair means")
            ax.set_title(g["group"], fontsize=9)
            ax.set_xlabel("per-pair mean error [m]")
            ax.legend(fontsize=8)
        fig.tight_layout()
        p = out / "tdoa_pair_bias.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


# -------------------------------------------------------------------------------------- the command
def calibrate(data_dir: Path, n_trials: int = 5, duration_s: float = 60.0, groups: Sequence[UtilGroup] = UTIL_GROUPS,
              twr: bool = True) -> dict[str, Any]:
    if not data_dir.is_dir():
        raise CalibrationError(f"real data directory {data_dir} not found (set UWB_HIL_DATA or use --data)")
    util = []
    for g in groups:
        real_files, real = real_util_trials(data_dir, g)
        sim_names, sim = sim_util_trials(data_dir, g, n_trials, duration_s)
        util.append({"group": g.name, "profile": g.profile, "mode": g.mode, "real_files": real_files,
                     "sim_flights": sim_names, "real": trial_summary(real), "sim": trial_summary(sim),
                     "real_trial_stats": [dict(t.row(), pair_means=t.pair_means) for t in real],
                     "sim_trial_stats": [dict(t.row(), pair_means=t.pair_means) for t in sim]})
    result: dict[str, Any] = {"data_dir": str(data_dir), "sim_trials": n_trials, "sim_duration_s": duration_s,
                              "util": util, "profiles": {p: asdict(sim_config(p)) for p in ("los", "nlos")}}
    if twr:
        links = rcv_twr_links(data_dir)
        result["twr"] = {"stats": twr_stats(links), "dependence": twr_dependence(links)}
        result["_links"] = links
    return result


def _f(x: float, d: int = 3) -> str:
    return "-" if x != x else f"{x:.{d}f}"


def format_report(res: dict[str, Any]) -> str:
    lines = []
    for g in res["util"]:
        lines.append(f"{g['group']}: {len(g['real_files'])} real trials vs {len(g['sim_flights'])} simulated "
                     f"({g['mode']}, profile {g['profile']}); mean over trials [min..max]")
        lines.append(f"  {'statistic':<14}{'real':>26}{'simulated':>26}{'sim/real':>10}")
        for key in STATS_KEYS[1:]:
            r, s = g["real"][key], g["sim"][key]
            d = 4 if key.startswith("frac") else 3
            ratio = s["mean"] / r["mean"] if r["mean"] not in (0.0,) and r["mean"] == r["mean"] else math.nan
            lines.append(f"  {key:<14}{_f(r['mean'], d):>10} [{_f(r['min'], d)}..{_f(r['max'], d)}]"
                         f"{_f(s['mean'], d):>10} [{_f(s['min'], d)}..{_f(s['max'], d)}]"
                         f"{_f(ratio, 2) if key in ('std', 'pair_spread') else '':>10}")
        lines.append("")
    if "twr" in res:
        st = res["twr"]["stats"]
        lines.append("rcv_twr TWR (5 sequences, 4 anchors; simulator error model at the recorded poses)")
        lines.append(f"  {'statistic':<14}{'real':>10}{'simulated':>12}")
        for key in ("mean", "median", "std", "centred_std", "frac_gt_0.3", "frac_gt_1", "pair_spread", "noise"):
            d = 4 if key.startswith("frac") else 3
            lines.append(f"  {key:<14}{_f(st['real'][key], d):>10}{_f(st['sim'][key], d):>12}")
        lines.append("  pose dependence (std of binned medians of the centred error) [m]:")
        for key, d in res["twr"]["dependence"].items():
            lines.append(f"    {key:<10} real {_f(d['amplitude']['real'])}  sim {_f(d['amplitude']['sim'])}   "
                         "medians real/sim by bin: " + " ".join(
                             f"{_f(a, 2)}/{_f(b, 2)}" for a, b in zip(d["real_median"], d["sim_median"])))
    return "\n".join(lines)


def add_parser(sub: Any) -> None:
    p = sub.add_parser("calibrate", help="simulated vs real UWB error statistics (UTIL TDoA, rcv_twr TWR)")
    p.add_argument("--data", help="real data directory (default ../shared/data or $UWB_HIL_DATA)")
    p.add_argument("--trials", type=int, default=5, help="simulated trials per group")
    p.add_argument("--duration", type=float, default=60.0, help="simulated trial length [s]")
    p.add_argument("--out", help="directory for the PNG plots")
    p.add_argument("--no-twr", action="store_true", help="skip the rcv_twr TWR comparison")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.set_defaults(func=cmd_calibrate)


def cmd_calibrate(args: argparse.Namespace) -> int:
    data = Path(args.data) if args.data else shared_data_dir()
    if args.trials < 1 or not args.duration > 20.0:
        raise ValueError("--trials must be >= 1 and --duration > 20 s (take-off and landing take 10 s)")
    res = calibrate(data, n_trials=args.trials, duration_s=args.duration, twr=not args.no_twr)
    links = res.pop("_links", None)
    if args.out:
        plots = write_plots(Path(args.out), links, res.get("twr", {}).get("dependence"), res["util"])
        res["plots"] = [str(p) for p in plots]
    if args.json:
        print(jsonsafe.dumps(res, indent=1))
    else:
        print(format_report(res))
        for p in res.get("plots", []):
            print(f"plot: {p}")
    return 0


__all__ = ["ErrorStats", "error_stats", "trial_summary", "UTIL_GROUPS", "UtilGroup", "real_util_trials",
           "sim_util_trials", "rcv_twr_links", "twr_dependence", "twr_stats", "calibrate", "format_report",
           "add_parser", "cmd_calibrate", "CalibrationError"]
