"""The report's figures (matplotlib, Agg; Figure objects, no pyplot state). Each returns None when the
campaign has nothing to show for it. Colours follow the paper: outlier rejection orange, + network blue."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from harness.report.data import CampaignData, RunMetrics
from harness.stream.results_file import OUTCOME_RESULT
from harness.kinds import KINDS, kind_named
from protocol.messages import Status

COLORS = {"none": "#8c8c8c", "outlier": "#ff7f0e", "outlier+nn": "#1f77b4", "outlier+nn+std": "#2ca02c"}
LABELS = {"none": "no rejection", "outlier": "outlier rejection", "outlier+nn": "outlier rejection + NN",
          "outlier+nn+std": "outlier rejection + NN + its std"}
MODES = ("twr", "tdoa")


def save(fig: Figure, path: Path, dpi: int = 100) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path


def _sim(data: CampaignData) -> list[RunMetrics]:
    return [r for r in data.accuracy_runs if r.source == "sim"]


def _sim_grid(data: CampaignData) -> tuple[list[RunMetrics], list[str], list[str]] | None:
    """The simulated runs with the modes and the trajectories they cover (a figure's rows and columns); None
    without a simulated run."""
    sim = _sim(data)
    modes = [m for m in MODES if any(r.mode == m for r in sim)]
    return (sim, modes, sorted({r.trajectory for r in sim})) if modes else None


def _configs(runs: list[RunMetrics]) -> list[str]:
    return [c for c in COLORS if any(r.config == c for r in runs)]


def rmse_boxes(data: CampaignData) -> Figure | None:
    """Paper Fig. 9: RMSE distribution over seeds, per mode, trajectory and configuration."""
    sim = _sim(data)
    modes = [m for m in MODES if any(r.mode == m for r in sim)]
    if not modes:
        return None
    fig = Figure(figsize=(5.2 * len(modes), 4.0), layout="constrained")
    axes = fig.subplots(1, len(modes), squeeze=False)[0]
    for ax, mode in zip(axes, modes):
        runs = [r for r in sim if r.mode == mode]
        trajs = sorted({r.trajectory for r in runs})
        cfgs = _configs(runs)
        width = 0.8 / max(1, len(cfgs))
        for ti, traj in enumerate(trajs):
            for ci, cfg in enumerate(cfgs):
                vals = [r.rmse for r in runs if r.trajectory == traj and r.config == cfg and math.isfinite(r.rmse)]
                if not vals:
                    continue
                pos = ti + (ci - (len(cfgs) - 1) / 2) * width
                bp = ax.boxplot([vals], positions=[pos], widths=width * 0.85, patch_artist=True,
                                showfliers=True, manage_ticks=False)
                for patch in bp["boxes"]:
                    patch.set_facecolor(COLORS[cfg])
                    patch.set_alpha(0.75)
                for med in bp["medians"]:
                    med.set_color("black")
        ax.set_xticks(range(len(trajs)))
        ax.set_xticklabels(trajs)
        ax.set_title(f"{mode.upper()}: position RMSE per flight")
        ax.set_ylabel("RMSE [m]")
        ax.grid(axis="y", alpha=0.3)
        for cfg in cfgs:
            ax.plot([], [], color=COLORS[cfg], lw=8, alpha=0.75, label=LABELS[cfg])
        ax.legend(fontsize=8)
    return fig


def error_over_time(data: CampaignData) -> Figure | None:
    """Paper Fig. 7: estimation error over time, mean over seeds with a +-1 std band."""
    grid = _sim_grid(data)
    if grid is None:
        return None
    sim, modes, trajs = grid
    fig = Figure(figsize=(5.5 * len(trajs), 3.2 * len(modes)), layout="constrained")
    axes = fig.subplots(len(modes), len(trajs), squeeze=False)
    for i, mode in enumerate(modes):
        for j, traj in enumerate(trajs):
            ax = axes[i][j]
            runs = [r for r in sim if r.mode == mode and r.trajectory == traj]
            for cfg in _configs(runs):
                curves = [r for r in runs if r.config == cfg and len(r.err_mean)]
                if not curves:
                    continue
                n = max(len(r.err_mean) for r in curves)
                stack = np.full((len(curves), n), np.nan)
                for k, r in enumerate(curves):
                    stack[k, :len(r.err_mean)] = r.err_mean
                t = curves[int(np.argmax([len(r.err_t_s) for r in curves]))].err_t_s
                with np.errstate(invalid="ignore"), _quiet():
                    mean = np.nanmean(stack, axis=0)
                    std = np.nanstd(stack, axis=0)
                ax.plot(t, mean, color=COLORS[cfg], lw=1.3, label=f"{LABELS[cfg]} (n={len(curves)})")
                ax.fill_between(t, mean - std, mean + std, color=COLORS[cfg], alpha=0.2, lw=0)
            ax.set_title(f"{mode.upper()} {traj}")
            ax.set_xlabel("time [s]")
            ax.set_ylabel("error |p - p_true| [m]")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    return fig


class _quiet:
    """Silence numpy's 'mean of empty slice' for bins where every seed has no sample."""

    def __enter__(self) -> None:
        import warnings
        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *exc: object) -> None:
        self._w.__exit__(*exc)


def _first_seed_run(runs: list[RunMetrics], mode: str, traj: str, cfg: str) -> RunMetrics | None:
    cands = [r for r in runs if r.mode == mode and r.trajectory == traj and r.config == cfg]
    return min(cands, key=lambda r: (r.seed if r.seed is not None else 0), default=None)


def paths_3d(data: CampaignData, max_points: int = 3000) -> Figure | None:
    """Paper Fig. 8 (top): estimated vs true 3-D paths of one flight per mode and trajectory."""
    grid = _sim_grid(data)
    if grid is None:
        return None
    sim, modes, trajs = grid
    fig = Figure(figsize=(5.0 * len(trajs), 4.6 * len(modes)), layout="constrained")
    for i, mode in enumerate(modes):
        for j, traj in enumerate(trajs):
            ax = fig.add_subplot(len(modes), len(trajs), i * len(trajs) + j + 1, projection="3d")
            truth_drawn = False
            title = f"{mode.upper()} {traj}"
            for cfg in ("outlier", "outlier+nn"):
                run = _first_seed_run(sim, mode, traj, cfg)
                if run is None:
                    continue
                flight = data.flight(run.flight_id)
                if not truth_drawn:
                    step = max(1, len(flight.truth_t_us) // max_points)
                    p = flight.truth_pos[::step]
                    ax.plot(p[:, 0], p[:, 1], p[:, 2], color="#d62728", lw=1.6, label="true")
                    truth_drawn = True
                    title += f" (seed {run.seed})"
                c = data.results(run.run_id).columns
                ok = c["outcome"] == OUTCOME_RESULT
                step = max(1, int(np.count_nonzero(ok)) // max_points)
                ax.plot(c["px"][ok][::step], c["py"][ok][::step], c["pz"][ok][::step], color=COLORS[cfg],
                        lw=0.8, label=LABELS[cfg])
            ax.set_title(title, fontsize=9)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.set_zlabel("z [m]")
            ax.legend(fontsize=7)
    return fig


_REJECTIONS = ((Status.REJECTED_KINEMATIC, "rejected: kinematic gate", "#ff7f0e"),
               (Status.REJECTED_CHI2, "rejected: chi-square gate", "#d62728"),
               (Status.REJECTED_GEOMETRY, "rejected: geometry", "#9467bd"),
               (Status.REJECTED_BASELINE, "rejected: beyond the anchors' distance", "#8c564b"))


def _scatter_rejections(ax: Axes, t: np.ndarray, err: np.ndarray, ok: np.ndarray, status: np.ndarray) -> None:
    """The measurements each gate rejected, one colour per gate, their count in the legend."""
    for code, name, color in _REJECTIONS:
        sel = ok & (status == code)
        if np.any(sel):
            ax.scatter(t[sel], err[sel], s=9, marker="x", color=color, label=f"{name} ({int(sel.sum())})")


def _clip_ylim(axes: tuple[Axes, ...], err: np.ndarray) -> None:
    """Every axis's y range: the 0.5-99.5 % range of the finite errors, padded by a quarter."""
    finite = err[np.isfinite(err)]
    if finite.size:
        lo, hi = np.percentile(finite, [0.5, 99.5])
        pad = 0.25 * (hi - lo + 1e-3)
        for ax in axes:
            ax.set_ylim(lo - pad, hi + pad)


def measurement_stream(data: CampaignData, mode: str) -> Figure | None:
    """Paper Fig. 4: one flight's measurement errors, the network's predicted bias (RESULT.bias of the
    outlier+nn run) and the measurements each gate rejected, coloured by gate."""
    sim = _sim(data)
    runs = [r for r in sim if r.mode == mode]
    if not runs:
        return None
    traj = sorted({r.trajectory for r in runs})[0]
    nn = _first_seed_run(runs, mode, traj, "outlier+nn") or _first_seed_run(runs, mode, traj, "outlier")
    if nn is None:
        return None
    flight = data.flight(nn.flight_id)
    c = data.results(nn.run_id).columns
    idx = c["index"]
    t = (flight.uwb_t_us[idx] - flight.uwb_t_us[0]) * 1e-6
    err = (flight.value - flight.true_value)[idx]
    ok = c["outcome"] == OUTCOME_RESULT
    fig = Figure(figsize=(11, 6.8), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True)
    ax.scatter(t[ok], err[ok], s=2, color="#b0b0b0", label="measurement error (z - h(p_true))", rasterized=True)
    has_nn = nn.config == "outlier+nn"
    if has_nn:
        ax.scatter(t[ok], c["bias"][ok], s=2, color=COLORS["outlier+nn"], label="predicted bias (NN)",
                   rasterized=True)
    _scatter_rejections(ax, t, err, ok, c["status"])
    _clip_ylim((ax, ax2), err)
    kind = kind_named(mode)
    ax.set_title(f"{kind.label} measurement stream: {nn.flight_id} ({nn.config}), every {kind.link}"
                 f"; y-axis clipped to the 0.5-99.5 % range", fontsize=9)
    ax.set_ylabel("[m]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, markerscale=3, loc="upper right")
    # One anchor (pair): the one with the largest mean error, where a bias the network should follow shows.
    key = kind.link_keys(flight.anchor_a[idx], flight.anchor_b[idx])
    keys, inv = np.unique(key[ok], return_inverse=True)
    if keys.size:
        mean_err = np.array([np.nanmean(err[ok][inv == k]) for k in range(keys.size)])
        k = int(np.nanargmax(np.abs(mean_err)))
        sel = np.zeros_like(ok)
        sel[np.nonzero(ok)[0][inv == k]] = True
        name = f"anchors {int(keys[k]) // 1000}->{int(keys[k]) % 1000}" if kind.n_anchors > 1 else f"anchor {keys[k]}"
        ax2.scatter(t[sel], err[sel], s=4, color="#b0b0b0", label=f"measurement error, {name}", rasterized=True)
        e_s = err[sel]
        win = max(1, min(51, e_s.size // 20))
        smooth = np.convolve(e_s, np.ones(win) / win, mode="same") if e_s.size > win else e_s
        ax2.plot(t[sel], smooth, color="black", lw=1.0, label=f"error, moving mean of {win}")
        if has_nn:
            ax2.plot(t[sel], c["bias"][sel], color=COLORS["outlier+nn"], lw=1.4, label="predicted bias (NN)")
        ax2.set_title(f"{name}: the one with the largest mean error ({mean_err[k]:+.3f} m)", fontsize=9)
        ax2.legend(fontsize=7, markerscale=3, loc="upper right")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("[m]")
    ax2.grid(alpha=0.3)
    return fig


def latency_histograms(data: CampaignData, budget_us: float) -> Figure | None:
    """Device compute time and end-to-end latency per message type, log-spaced bins, 5 ms budget marked."""
    present = [(k.code, k.label) for k in KINDS.values() if any(r.kind == k.code for r in data.measurement_runs)]
    if not present:
        return None
    fig = Figure(figsize=(11, 3.4 * len(present)), layout="constrained")
    axes = fig.subplots(len(present), 2, squeeze=False)
    for i, (kind, name) in enumerate(present):
        runs = [r for r in data.measurement_runs if r.kind == kind]
        e2e, e2e_pacing = data.e2e_runs(kind)
        for j, (label, arr) in enumerate((("device compute", np.concatenate([r.compute_us for r in runs])),
                                          (f"end to end, {e2e_pacing} pacing",
                                           np.concatenate([r.rtt_us for r in e2e])))):
            ax = axes[i][j]
            v = arr[np.isfinite(arr) & (arr > 0)]
            if v.size:
                lo, hi = max(v.min(), 1e-2), max(v.max(), budget_us * 1.5 if j == 1 else v.max()) * 1.05
                bins = np.logspace(math.log10(lo), math.log10(hi), 60)
                ax.hist(v, bins=bins, color="#1f77b4" if j == 0 else "#2ca02c", alpha=0.8, histtype="stepfilled")
                ax.set_xscale("log")
                ax.set_yscale("log")
                p50, p99 = np.percentile(v, [50, 99])
                ax.axvline(p50, color="black", lw=0.8, ls="--", label=f"p50 {p50:.1f} us")
                ax.axvline(p99, color="black", lw=0.8, ls=":", label=f"p99 {p99:.1f} us")
            if j == 1 or (v.size and v.max() > budget_us):
                ax.axvline(budget_us, color="#d62728", lw=1.2, label=f"budget {budget_us / 1e3:.0f} ms")
            ax.set_title(f"{name}: {label} (n={v.size})", fontsize=9)
            ax.set_xlabel("[us]")
            ax.set_ylabel("count")
            ax.legend(fontsize=7)
    return fig


def recorded_bars(data: CampaignData, diverged_m: float = 10.0) -> Figure | None:
    """RMSE per recorded (held-out) flight and configuration, one panel per mode. Bars of diverged runs
    (RMSE above diverged_m) are clipped and labelled with their value, so they do not flatten the rest."""
    from harness.campaign.recorded_usd import is_usd   # the Crazyflie logs: harness/report/usd_section.py
    rec = [r for r in data.accuracy_runs if r.source == "recorded" and not is_usd(r.trajectory)]
    if not rec:
        return None
    modes = [m for m in MODES if any(r.mode == m for r in rec)]
    fig = Figure(figsize=(max(6.0, 1.3 * len({r.flight_id for r in rec}) + 3), 4.2), layout="constrained")
    axes = fig.subplots(1, len(modes), squeeze=False,
                        width_ratios=[len({r.flight_id for r in rec if r.mode == m}) + 1 for m in modes])[0]
    for ax, mode in zip(axes, modes):
        runs = [r for r in rec if r.mode == mode]
        fids = sorted({r.flight_id for r in runs})
        cfgs = _configs(runs)
        width = 0.8 / max(1, len(cfgs))
        sane = [r.rmse for r in runs if math.isfinite(r.rmse) and r.rmse <= diverged_m]
        top = 1.25 * max(sane) if sane else diverged_m
        for ci, cfg in enumerate(cfgs):
            vals = np.array([next((r.rmse for r in runs if r.flight_id == f and r.config == cfg), np.nan)
                             for f in fids])
            x = np.arange(len(fids)) + (ci - (len(cfgs) - 1) / 2) * width
            ax.bar(x, np.minimum(vals, top), width * 0.9, color=COLORS[cfg], label=LABELS[cfg])
            for xi, v in zip(x, vals):
                if math.isfinite(v) and v > top:
                    ax.text(xi, top * 0.97, f"diverged\n{v:.3g} m", rotation=90, ha="center", va="top", fontsize=7)
        ax.set_ylim(0, top)
        ax.set_xticks(range(len(fids)))
        ax.set_xticklabels([f.removeprefix(f"rec-{mode}-") for f in fids], rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("RMSE [m]")
        ax.set_title(f"{mode.upper()}: recorded, held out", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=7)
    return fig
