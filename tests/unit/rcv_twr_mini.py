"""The synthetic rcv_twr sequence the loader tests read (test_loaders.py, test_native_format.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_rcv_twr_mini(d: Path) -> Path:
    """A synthetic rcv_twr sequence in `d` (written here, not committed: the real ones are only read from
    ../shared/data): 4 anchors, exact ranges (1 cm resolution) to a tag moving in a straight line, round
    robin every 40 ms, gt at 10 ms, one failed ranging (-1.5) on anchor 2."""
    d.mkdir(parents=True, exist_ok=True)
    anchors = {1: (2.0, 2.0, 1.0), 2: (-2.0, 2.0, 1.2), 3: (-2.0, -2.0, 0.8), 4: (2.0, -2.0, 1.1)}
    offset = np.array([0.0, -0.05, 0.045])   # the antenna offset this data folder's README states
    (d.parent / "README.md").write_text("- `anchor.yaml`: anchor positions.\n  The source's own analysis adds "
                                        "(0, -0.05, +0.045) m to the anchor positions (antenna offset).\n")

    def ts(t: float) -> str:
        s = 13.0 + t
        return f"2024-06-09 19:39:{int(s):02d}.{int(round((s % 1) * 1e6)):06d}"

    def tag(t: float) -> np.ndarray:
        return np.array([0.2 * t, -0.1 * t, 0.5 + 0.05 * t])

    (d / "anchor.yaml").write_text("".join(
        f"anchor{k}:\n  - position:\n      data: [{p[0]}, {p[1]}, {p[2]}]\n  - orientation:\n"
        f"      data: [0.0, 0.0, 0.0, 1.0]\n\n" for k, p in anchors.items()))
    gt = ["Time,Position X,Position Y,Position Z,Orientation X,Orientation Y,Orientation Z,Orientation W"]
    for k in range(121):
        t = 0.01 * k
        p = tag(t)
        gt.append(f"{ts(t)},{p[0]:.9f},{p[1]:.9f},{p[2]:.9f},0.0,0.0,0.0,1.0")
    (d / "gt.csv").write_text("\n".join(gt) + "\n")
    for k, a in anchors.items():
        rows = ["Time,Address,Range,Rxpower,Position X,Position Y,Position Z,Orientation X,Orientation Y,"
                "Orientation Z,Orientation W"]
        for j in range(7):
            t = 0.02 + 0.16 * j + 0.04 * (k - 1)
            p = tag(t)
            rng = f"{np.linalg.norm(p - (np.array(a) + offset)):.2f}" if not (k == 2 and j == 3) else "-1.5"
            rows.append(f"{ts(t)},{80 + k},{rng},-62.5,{p[0]:.9f},{p[1]:.9f},{p[2]:.9f},0.0,0.0,0.0,1.0")
        (d / f"anchor_{k}.csv").write_text("\n".join(rows) + "\n")
    return d
