"""Twin of firmware_sim/core/estimator_anchors.c: the estimator's anchor table, MAX_ANCHORS slots keyed by
any 8-bit id. Host positions stay; radio (LPP) positions are valid RADIO_POS_VALID_MS after the last packet
that carried one. The per-anchor state of the gates, the pair monitor and the bias states is kept by slot."""

from __future__ import annotations

import numpy as np

RADIO_POS_VALID_MS = 2000   # ESTIMATOR_RADIO_POS_VALID_MS
WRAP32 = 1 << 32


class AnchorTable:
    def __init__(self, n_slots: int) -> None:
        self.positions: dict[int, np.ndarray] = {}       # id -> position (what the supervisor's box uses)
        self.ids: list[int | None] = [None] * n_slots    # the id each slot holds
        self.ms: list[int | None] = [None] * n_slots     # radio positions: when received [ms]; None = host

    def store(self, anchor_id: int, pos: np.ndarray, ms: int | None) -> bool:
        """Host (ms None) or radio position; False if the id is not 8-bit or no slot is left."""
        if not 0 <= anchor_id <= 255:
            return False
        slot = self.ids.index(anchor_id) if anchor_id in self.ids else None
        if slot is not None and ms is not None and self.ms[slot] is None:
            return True   # positions configured by the host stay
        slot = slot if slot is not None else self._new_slot()
        if slot is None:
            return False
        self.ids[slot], self.ms[slot] = anchor_id, ms
        self.positions[anchor_id] = np.asarray(pos, dtype=np.float64).reshape(3).copy()
        return True

    def _new_slot(self) -> int | None:
        """The first free slot, else the radio position received longest ago (32-bit ms arithmetic)."""
        if None in self.ids:
            return self.ids.index(None)
        best: int | None = None
        for k, ms in enumerate(self.ms):
            if ms is not None and (best is None or (ms - self.ms[best]) % WRAP32 >= WRAP32 // 2):  # type: ignore[operator]
                best = k
        if best is not None:
            del self.positions[self.ids[best]]   # type: ignore[index]
        return best

    def slot(self, anchor_id: int, t_us: int) -> int | None:
        """The slot of a position valid at t_us, else None."""
        aid = int(anchor_id)
        if aid not in self.ids:
            return None
        k = self.ids.index(aid)
        ms = self.ms[k]
        return k if ms is None or ((int(t_us) // 1000) - ms) % WRAP32 < RADIO_POS_VALID_MS else None
