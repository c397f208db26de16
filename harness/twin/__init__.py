"""The numpy twin: a readable float64 reference of the firmware estimator (firmware_sim/core).

It is the test oracle: the C firmware must reproduce its statuses exactly and its estimates to
float32 precision. Module map (one per C file): ``ekf`` (ekf_core.c, ekf_predict.c, ekf_update.c), ``measurements``
(mm_twr.c, mm_tdoa.c), ``gates`` (gate_kinematic.c, gate_chi2.c), ``features`` (bias_nn_features),
``estimator`` (estimator.c).
"""

from harness.twin.estimator import TwinError, TwinEstimator, TwinResult, run_flight

__all__ = ["TwinError", "TwinEstimator", "TwinResult", "run_flight"]
