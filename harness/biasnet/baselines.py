"""Simple calibrations the network has to beat, fitted on the same training samples.

* :class:`PairConstant` — one constant bias per anchor pair (per anchor for TWR): what the authors'
  on-board code offers as ``Constant_Bias``.
* :class:`VoxelTable` — the mean bias per anchor pair in each cube of a 3-D grid over the tag position,
  falling back to the pair constant where a voxel saw too few samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from harness.biasnet.dataset import Samples


@dataclass
class PairConstant:
    name: str = "pair-constant"
    table: dict[int, float] = field(default_factory=dict)
    fallback: float = 0.0

    def fit(self, s: Samples) -> "PairConstant":
        keys = s.pair_keys()
        self.fallback = float(np.mean(s.bias)) if len(s) else 0.0
        self.table = {int(k): float(np.mean(s.bias[keys == k])) for k in np.unique(keys)}
        return self

    def predict(self, s: Samples) -> np.ndarray:
        keys = s.pair_keys()
        return np.array([self.table.get(int(k), self.fallback) for k in keys], dtype=np.float64)


@dataclass
class VoxelTable:
    """Mean bias per (pair, voxel); tag position = anchor_a - dp (the first three features)."""

    voxel_m: float = 0.5
    min_count: int = 10
    name: str = "voxel-table"
    table: dict[tuple[int, int, int, int], float] = field(default_factory=dict)
    const: PairConstant = field(default_factory=PairConstant)

    def _cells(self, s: Samples) -> tuple[np.ndarray, np.ndarray]:
        if s.anchor_pos is None:
            raise ValueError("the voxel table needs the samples' anchor positions")
        tag = s.anchor_pos[:, :3] - s.x[:, :3]
        return s.pair_keys(), np.floor(tag / self.voxel_m).astype(np.int64)

    def fit(self, s: Samples) -> "VoxelTable":
        self.const = PairConstant().fit(s)
        keys, cells = self._cells(s)
        rows = np.concatenate([keys[:, None], cells], axis=1)
        uniq, inv, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
        sums = np.bincount(inv.ravel(), weights=s.bias, minlength=len(uniq))
        self.table = {tuple(int(v) for v in u): float(sums[i] / counts[i])  # type: ignore[misc]
                      for i, u in enumerate(uniq) if counts[i] >= self.min_count}
        return self

    def predict(self, s: Samples) -> np.ndarray:
        keys, cells = self._cells(s)
        fallback = self.const.predict(s)
        out = np.empty(len(s))
        for i in range(len(s)):
            out[i] = self.table.get((int(keys[i]), *(int(c) for c in cells[i])), fallback[i])  # type: ignore[arg-type]
        return out
