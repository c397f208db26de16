"""The campaign report's bias-network section: the paper's Fig. 5 (measured error and predicted bias vs
azimuth) on a simulated spin in place with the campaign's default network, and on the real heading sweep
(rcv_twr sequence 3) with its rcv_twr network; plus those networks' held-out measurement figures.

Everything comes from the campaign directory (DIR/models, written by harness/campaign/models.py when the
campaign ran), never from the checkout: the same directory always gives the same report."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from harness.biasnet.network import BiasModel

if TYPE_CHECKING:
    from harness.report.html import Section
    from harness.report.context import ReportContext

SPIN_SEED = 1100  # an evaluation seed (>= 1000): a flight the network never saw


def _figure(ctx: "ReportContext", model: BiasModel, flight: Any, name: str, caption: str) -> list[Any]:
    from harness.biasnet.plots import bias_vs_azimuth
    from harness.report.html import FigureRef
    path = bias_vs_azimuth(model, flight, ctx.fig_dir / f"{name}.png")
    return [FigureRef(path, caption)]


def _heldout_rows(summary: dict[str, Any]) -> list[list[str]]:
    rows = []
    for key in ("sim", "util_tdoa_pos", "rcv_twr"):
        entry = summary.get(key)
        if not isinstance(entry, dict):
            continue
        groups = ({f"{key} {m}": entry[m]["heldout"] for m in ("twr", "tdoa") if m in entry} if key == "sim"
                  else {f"{key} {name}": res for name, res in entry.get("heldout", {}).items()})
        for label, methods in groups.items():
            net = methods.get("network", {})
            rows.append([label, str(net.get("n", "-")), f"{net.get('rmse_raw', float('nan')):.4f}"]
                        + [f"{100 * methods[m]['reduction']:.1f} %" if m in methods else "-"
                           for m in ("network", "pair-constant", "voxel-table")]
                        + [_share(methods.get(m, {}), key) for key in ("share_of_ceiling", "share_of_ceiling_unbiased")
                           for m in ("network", "voxel-table")])
    return rows


def _share(m: dict[str, Any], key: str = "share_of_ceiling") -> str:
    """share_of_ceiling or share_of_ceiling_unbiased (ceiling.py) when the summary has it (models.json
    written since it exists)."""
    v = m.get(key)
    return f"{100 * v:.0f} %" if isinstance(v, (int, float)) and v == v else "-"


def bias_section(ctx: "ReportContext") -> "Section | None":
    from harness.campaign.models import model_path, read_index
    from harness.flight.scenarios import scenario_flight
    from harness.report.html import Section, Table
    root = ctx.data.root
    index = read_index(root)
    default = model_path(root, index, index.get("default")) if index else None
    if index is None or default is None:
        return None        # a campaign directory without its networks: nothing to show about them
    sec = Section("bias-network", "Bias network: predicted bias vs azimuth (paper Fig. 5)")
    model = BiasModel.load(default)
    spin = scenario_flight("spin", mode="twr", duration_s=30.0, seed=SPIN_SEED)
    sec.figures += _figure(ctx, model, spin, "fig5_sim_spin",
                           f"Simulated spin in place (seed {SPIN_SEED}, unseen in training): measured TWR error "
                           f"and the campaign's default network's bias (model {model.hash_hex}).")
    rcv_model = model_path(root, index, (index.get("families") or {}).get("rcv_twr"))
    if rcv_model is not None and index.get("fig5_rcv_flight"):
        from harness.flight.native import load_flight
        sec.figures += _figure(ctx, BiasModel.load(rcv_model), load_flight(root / "models" / index["fig5_rcv_flight"]),
                               "fig5_rcv_heading_sweep",
                               "Real heading sweep (rcv_twr sequence 3, part of that network's training set): "
                               "measured TWR error and the network's bias.")
    sec.paragraphs += [str(n) for n in index.get("notes") or []]   # what was left out of DIR/models, and why
    summary = index.get("summary") or {}
    rows = _heldout_rows(summary)
    if rows:
        sec.paragraphs.append("Share of ceiling = (RMSE raw - RMSE corrected) / (RMSE raw - floor); floor = RMSE of "
                              "the error minus its per-pair moving average over +-0.25 s (the issue's definition). "
                              "That average includes the sample itself, so with n samples in the window white noise "
                              "leaves only sqrt(1 - 1/n) of its std: the unbiased floor scales each residual's square "
                              "by n/(n-1) (windows of one sample left out), a lower ceiling where windows are short "
                              "(TDoA3).")
        sec.tables.append(Table(["network / held-out data", "n", "RMSE raw [m]", "network", "pair constant",
                                 "voxel table", "network: share of ceiling", "voxel table: share of ceiling",
                                 "network: share (unbiased floor)", "voxel table: share (unbiased floor)"],
                                rows))
    sec.data = {"models": {k: v for k, v in sorted((index.get("families") or {}).items())},
                "default_model": index.get("default")}
    return sec
