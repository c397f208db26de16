"""The calibration figures: TWR error vs relative pose, TDoA per-pair bias histograms."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from harness.calibrate.rcv_twr import ANGLE_BINS, TwrLinks, centered


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
            c = centered(links, links.err_real)
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
