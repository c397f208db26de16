"""The supervisor's checks (twin of firmware_sim/core/supervisor.c): is the state sane, and if not, why.
The restart itself is TwinEstimator._supervise (it replaces the estimator's filter)."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from harness.config import EstimatorConfig
from harness.twin.ekf import POS, ErrorStateEkf
from protocol.messages import ResultFlag

#: beyond this |position| [m] the state counts as diverged even without anchors (EST_MAX_ABS_POSITION)
MAX_ABS_POSITION = 1e5
#: no UWB measurement for this long [us] is a measurement gap (EST_GAP_US)
GAP_US = 1_000_000

# protocol enum result_flag: the reasons, as plain ints
FLAG_NON_FINITE = int(ResultFlag.NON_FINITE)
FLAG_OUT_OF_BOX = int(ResultFlag.OUT_OF_BOX)
FLAG_SPEED = int(ResultFlag.SPEED)
FLAG_COVARIANCE = int(ResultFlag.COVARIANCE)
FLAG_GAP_RESTART = int(ResultFlag.GAP_RESTART)


def reason(ekf: ErrorStateEkf, config: EstimatorConfig, anchors: Mapping[int, np.ndarray],
           t_uwb_us: int | None) -> int:
    """0 if the state is sane, else the FLAG_* reason (supervisor.c supervisor_reason)."""
    c = config
    if not ekf.is_finite():
        return FLAG_NON_FINITE
    p = ekf.x[POS]
    if bool(np.any(np.abs(p) > MAX_ABS_POSITION)):
        return FLAG_OUT_OF_BOX
    if anchors:
        box = np.array(list(anchors.values()))
        if bool(np.any(p < box.min(axis=0) - c.sup_margin) or np.any(p > box.max(axis=0) + c.sup_margin)):
            return FLAG_OUT_OF_BOX
    if float(np.sum(ekf.x[3:6] ** 2)) > c.sup_max_speed ** 2:
        return FLAG_SPEED
    if bool(np.any(np.diagonal(ekf.P)[:3] > variance_bounds(c))):
        # a divergence only while measurements arrive: without any, P grows by construction
        return FLAG_GAP_RESTART if measurement_gap(ekf, t_uwb_us) else FLAG_COVARIANCE
    return 0


def variance_bounds(config: EstimatorConfig) -> np.ndarray:
    """The bounds on the position variances: sup_max_var, never below the initial ones."""
    c = config
    return np.maximum([c.init_std_xy ** 2, c.init_std_xy ** 2, c.init_std_z ** 2], c.sup_max_var)


def measurement_gap(ekf: ErrorStateEkf, t_uwb_us: int | None) -> bool:
    """No UWB measurement for GAP_US up to the state's time, or none yet (supervisor.c measurement_gap)."""
    if t_uwb_us is None:
        return True
    return ekf.t_us is not None and ekf.t_us - t_uwb_us >= GAP_US
