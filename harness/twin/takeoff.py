"""Take-off and touchdown detector of a vehicle that starts on the floor (twin of firmware_sim/core/takeoff.c):
until the climb shows in the thrust-axis accelerometer, and again after a touchdown's shock, the estimator
gates without re-opening (the floor's NLOS, takeoff.h)."""

from __future__ import annotations

from dataclasses import dataclass

from harness.twin.ekf import GRAVITY

TAU_S = 1.0        # TAKEOFF_TAU_S
CLIMB_V = 0.3      # TAKEOFF_CLIMB_V [m/s]
MAX_DT_S = 0.1     # TAKEOFF_MAX_DT_S
TOUCH_ACC = 5.0    # TAKEOFF_TOUCH_ACC [m/s^2] above g: a touchdown
FLOOR_HOLD_US = 200_000   # TAKEOFF_FLOOR_HOLD_US: a range to the floor's "on the floor" holds this long


@dataclass
class TakeoffDetector:
    climb_v: float = 0.0
    t_us: int | None = None
    airborne: bool = False
    floor: bool = False            # the last range to the floor said: on the floor
    t_floor_us: int = 0

    def on_imu(self, t_us: int, acc_z: float, r22: float) -> bool:
        """One IMU sample: acc_z the thrust-axis specific force [m/s^2], r22 = R[2][2] of the attitude (1 without
        one). A shock above TOUCH_ACC is a touchdown: on the floor again until the next climb."""
        up = r22 * acc_z - GRAVITY
        if up > TOUCH_ACC:
            self.climb_v, self.airborne = 0.0, False
        elif self.t_us is not None and t_us > self.t_us:
            dt = (t_us - self.t_us) * 1e-6
            if dt <= MAX_DT_S:
                self.climb_v += dt * up - self.climb_v * (dt / TAU_S)
        self.t_us = t_us
        if self.climb_v > CLIMB_V:
            self.airborne = True
        return self.airborne

    def on_floor_range(self, t_us: int, on_floor: bool) -> None:
        """A range to the floor (a kind with floor_below: the ToF ranger) at t_us said on the floor or not."""
        self.floor, self.t_floor_us = bool(on_floor), int(t_us)

    def on_floor(self, imu_floor: bool, t_us: int) -> bool:
        """The IMU says so (imu_floor: before the climb, after a touchdown), or a range to the floor said so within
        FLOOR_HOLD_US."""
        if imu_floor and not self.airborne:
            return True
        return self.floor and 0 <= t_us - self.t_floor_us < FLOOR_HOLD_US
