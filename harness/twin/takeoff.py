"""Take-off detector of the quadrotor IMU model (twin of firmware_sim/core/takeoff.c): until the climb shows in
the thrust-axis accelerometer, the estimator gates without re-opening (the floor's NLOS, takeoff.h)."""

from __future__ import annotations

from dataclasses import dataclass

from harness.twin.ekf import GRAVITY

TAU_S = 1.0        # TAKEOFF_TAU_S
CLIMB_V = 0.3      # TAKEOFF_CLIMB_V [m/s]
MAX_DT_S = 0.1     # TAKEOFF_MAX_DT_S


@dataclass
class TakeoffDetector:
    climb_v: float = 0.0
    t_us: int | None = None
    airborne: bool = False

    def on_imu(self, t_us: int, acc_z: float, r22: float) -> bool:
        """One IMU sample: acc_z the thrust-axis specific force [m/s^2], r22 = R[2][2] of the attitude."""
        if self.t_us is not None and t_us > self.t_us:
            dt = (t_us - self.t_us) * 1e-6
            if dt <= MAX_DT_S:
                self.climb_v += dt * (r22 * acc_z - GRAVITY) - self.climb_v * (dt / TAU_S)
        self.t_us = t_us
        if self.climb_v > CLIMB_V:
            self.airborne = True
        return self.airborne
