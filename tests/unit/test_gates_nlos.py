"""The chi-square gate's lock-out guard on a real obstacle flight (UTIL const3 trial 2, UWB-only, numpy twin
= the firmware core; skipped when ../shared/data/util is absent). Without the guard the gates lock anchors
out for long stretches among obstacles (and lose to no rejection by 17 %); with it no anchor's links stay
rejected much beyond the guard time and the position error shrinks (docs/bias-network.md "Outlier rejection among
obstacles")."""

from __future__ import annotations

import numpy as np
import pytest

from harness.flight.loaders import load_recordings
from harness.config import PRESETS
from harness.flight.data import Flight
from harness.flight.run_config import config_for
from harness.paths import shared_data_dir
from harness.twin import gates
from harness.twin.estimator import ACCEPTED, TwinEstimator

UTIL = shared_data_dir() / "util"
FLIGHT = UTIL / "const3" / "const3-trial2-tdoa2-extracted.csv"


class _WithoutGuard(TwinEstimator):
    def _chi2_reopened(self) -> bool:
        return False


def _replay(flight: Flight, stages: int, cls: type[TwinEstimator]) -> tuple[np.ndarray, np.ndarray]:
    twin = cls(config_for(flight, stages=stages, uwb_only=True), flight.anchors.as_dict())
    u = flight.uwb
    res = [twin.on_tdoa(int(t), int(a), int(b), float(v)) for t, a, b, v in zip(u.t_us, u.anchor_a, u.anchor_b, u.value)]
    return np.array([r.pos for r in res]), np.array([r.status for r in res])


def _longest_lockout_s(flight: Flight, status: np.ndarray) -> float:
    """The longest time any anchor went without a fused link while its links kept arriving."""
    u = flight.uwb
    longest, last_fused = 0.0, {}
    for t, a, b, s in zip(u.t_us, u.anchor_a, u.anchor_b, status):
        for i in (int(a), int(b)):
            if s == ACCEPTED:
                last_fused[i] = int(t)
            elif i in last_fused:
                longest = max(longest, (int(t) - last_fused[i]) * 1e-6)
    return longest


@pytest.mark.skipif(not FLIGHT.is_file(), reason=f"{FLIGHT} is absent")
def test_guard_ends_lockouts_on_a_real_obstacle_flight() -> None:
    flight = load_recordings([FLIGHT], UTIL / "anchors.csv")[0]
    truth = flight.truth.position_at(flight.uwb.t_us)

    def rmse(pos: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((pos - truth) ** 2, axis=1))))

    p_old, s_old = _replay(flight, PRESETS["outlier"], _WithoutGuard)
    p_new, s_new = _replay(flight, PRESETS["outlier"], TwinEstimator)
    guard_s = gates.CHI2_REOPEN_US * 1e-6
    assert _longest_lockout_s(flight, s_old) > 2 * guard_s            # locked out without the guard
    assert _longest_lockout_s(flight, s_new) < guard_s + 0.1          # at most the guard time + a few links
    assert rmse(p_new) < rmse(p_old) - 0.01                          # and the gates' loss shrinks
