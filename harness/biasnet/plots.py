"""The paper's Fig. 5: measured error and the network's predicted bias against the azimuth of the anchor
seen from the tag (body frame), for one anchor (pair) of a flight: a spin in place sweeps it. With the
attitude truth of a real flight (Crazyflie uSD logs), also against the anchor's elevation in the body frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from harness.biasnet.dataset import XI_DEFAULT, flight_samples
from harness.biasnet.network import BiasModel
from harness.errors import InputError
from harness.flight.data import Flight
from harness.kinds import kind_of


def _rotate_world_to_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v (N, 3) world -> body with q (N, 4) (w, x, y, z) body->world: R^T v."""
    w, x, y, z = (q[:, k] for k in range(4))
    r = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                  np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                  np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)
    return np.einsum("nji,nj->ni", r, v)


def azimuth_series(model: BiasModel, flight: Flight) -> dict[str, np.ndarray | str]:
    """For the most measured anchor (pair): azimuth [deg], measured error and predicted bias [m]."""
    kind = kind_of(flight.uwb.kind).key
    net = model.network(kind)
    if net is None:
        raise InputError(f"the model has no {kind} network")
    s = flight_samples(flight, net.layout, XI_DEFAULT)
    if s.anchor_pos is None or len(s) == 0:
        raise InputError(f"{flight.name}: no samples to plot")
    keys, counts = np.unique(s.pair, axis=0, return_counts=True)
    a, b = (int(v) for v in keys[int(np.argmax(counts))])
    m = (s.pair[:, 0] == a) & (s.pair[:, 1] == b)
    dp = s.x[m, :3]  # anchor A - tag, world
    if flight.truth.quat is not None and s.row is not None:
        q = flight.truth.quat_at(flight.uwb.t_us[s.row[m]])
        d_body = _rotate_world_to_body(q, dp)
    else:
        d_body = dp  # no attitude (e.g. the UTIL reduction): level flight, yaw 0 assumed
    az = np.degrees(np.arctan2(d_body[:, 1], d_body[:, 0]))
    el = np.degrees(np.arctan2(d_body[:, 2], np.hypot(d_body[:, 0], d_body[:, 1])))
    label = f"anchor {a}" if b < 0 else f"anchor {a} (pair {a}-{b})"
    return {"azimuth_deg": az, "elevation_deg": el, "error": s.bias[m], "predicted": net.predict_batch(s.x[m]),
            "label": label}


def _panel(ax: "Any", d: dict[str, np.ndarray | str], angle: str) -> None:
    """Measured error and predicted bias against d[angle + "_deg"] on one axis."""
    x = np.asarray(d[f"{angle}_deg"])
    order = np.argsort(x)
    ax.scatter(x, np.asarray(d["error"]), s=4, alpha=0.35, color="tab:blue", label="measured error (meas - true)")
    ax.plot(x[order], np.asarray(d["predicted"])[order], ".", ms=2.5, color="tab:red", label="network bias")
    ax.set_xlabel(f"{angle} of {d['label']} seen from the tag, body frame [deg]")
    ax.set_ylabel("error / bias [m]")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", markerscale=4)


def bias_vs_azimuth(model: BiasModel, flight: Flight, path: Path, note: str = "", elevation: bool = False) -> Path:
    """The figure as a PNG at `path`; `elevation`: a second panel against the anchor's body-frame elevation."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = azimuth_series(model, flight)
    angles = ("azimuth", "elevation") if elevation else ("azimuth",)
    fig, axes = plt.subplots(1, len(angles), figsize=(8 * len(angles), 4), dpi=110, squeeze=False)
    for ax, angle in zip(axes[0], angles):
        _panel(ax, d, angle)
    what = " and elevation" if elevation else ""
    fig.suptitle(f"{flight.name}: measured error and predicted bias vs azimuth{what}" + (f" ({note})" if note else ""))
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
