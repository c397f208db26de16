"""Error-state EKF (twin of firmware_sim/core/ekf_core.c, ekf_predict.c, ekf_update.c), written from the
equations in float64.

Error state ``x`` (9,): world position (0..2), **body-frame** velocity (3..5), attitude error
(6..8, a body-frame rotation vector that is zero outside an update). The attitude itself is the
quaternion ``q`` (w, x, y, z), Hamilton, body -> world, with rotation matrix ``R``.

Process noise (same model as the C file comment): continuous white acceleration, so the injected
uncertainty does not depend on the prediction rate.

* IMU mode, step ``dt``, ``Sa = diag(acc_xy^2, acc_xy^2, acc_z^2)`` (body frame):
  ``Q_vv = Sa dt``, ``Q_pv = R Sa dt^2/2``, ``Q_pp = R Sa R^T dt^3/3``,
  ``Q_dd = diag(g_rp^2, g_rp^2, g_yaw^2) dt``.
* UWB-only mode, per axis, ``q = proc_cv_acc``: ``Q_pp = q^2 dt^3/3``, ``Q_pv = q^2 dt^2/2``,
  ``Q_vv = q^2 dt``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

N = 9
GRAVITY = 9.81
P_MIN = 1e-6
P_MAX = 100.0
PREDICT_INTERVAL_US = 10_000
INIT_STD_VEL = 0.5
INIT_STD_ATT = 0.01
GYRO_NOISE_RP = 0.01
GYRO_NOISE_YAW = 0.01
ATT_ERR_MAX = 10.0

POS = slice(0, 3)
VEL = slice(3, 6)
ATT = slice(6, 9)


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3), body -> world, of the unit quaternion ``q`` (4,) = (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ])


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a (x) b`` of two quaternions (4,)."""
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return np.concatenate([[aw * bw - av @ bv], aw * bv + bw * av + np.cross(av, bv)])


def quat_exp(v: np.ndarray) -> np.ndarray:
    """Unit quaternion (4,) of the rotation vector ``v`` (3,) [rad]."""
    theta = float(np.linalg.norm(v))
    s = np.sin(0.5 * theta) / theta if theta > 1e-6 else 0.5
    return np.concatenate([[np.cos(0.5 * theta)], s * v])


def quat_rotate_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``normalise(q (x) exp(v))``: apply the body-frame rotation vector ``v`` (3,) to ``q`` (4,)."""
    out = quat_mul(q, quat_exp(v))
    return out / np.linalg.norm(out)


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (3,) [rad] of ``q`` (4,) (formulas of docs/ARCHITECTURE.md)."""
    w, x, y, z = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` (3, 3) with ``[v]x u = v x u``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def attitude_block(d: np.ndarray) -> np.ndarray:
    """Second-order rotation ``G`` (3, 3) of the attitude-error covariance for half-angles ``d`` (3,)."""
    d0, d1, d2 = d
    return np.array([
        [1 - d1 * d1 / 2 - d2 * d2 / 2, d2 + d0 * d1 / 2, -d1 + d0 * d2 / 2],
        [-d2 + d0 * d1 / 2, 1 - d0 * d0 / 2 - d2 * d2 / 2, d0 + d1 * d2 / 2],
        [d1 + d0 * d2 / 2, -d0 + d1 * d2 / 2, 1 - d0 * d0 / 2 - d1 * d1 / 2],
    ])


def sym_clamp(P: np.ndarray) -> np.ndarray:
    """Symmetrise ``(P + P^T)/2`` and bound it as ekf_core.c does, keeping it positive semi-definite.

    A variance above P_MAX scales its row and column by ``sqrt(P_MAX / P_ii)`` (a congruence: PSD and
    the correlation coefficients are kept; clamping entries one by one made P indefinite, S < 0, and
    an update threw the state kilometres away). A non-finite variance becomes P_MAX without
    correlations; other NaN -> 0; ``|P_ij| <= P_MAX``; ``P_ii >= P_MIN``.

    Parameters
    ----------
    P : ndarray, shape (9, 9)
        Covariance, possibly slightly asymmetric after a product.

    Returns
    -------
    ndarray, shape (9, 9)
        A new symmetric, bounded matrix.
    """
    S = 0.5 * (P + P.T)
    d = np.diagonal(S).copy()
    bad = ~np.isfinite(d)
    scale = np.ones(len(d))
    big = ~bad & (d > P_MAX)
    scale[big] = np.sqrt(P_MAX / d[big])
    with np.errstate(invalid="ignore"):
        S = S * np.outer(scale, scale)
    S[bad, :] = 0.0
    S[:, bad] = 0.0
    S = np.clip(np.where(np.isnan(S), 0.0, S), -P_MAX, P_MAX)
    d = np.diagonal(S).copy()
    d[bad] = P_MAX
    np.fill_diagonal(S, np.clip(d, P_MIN, P_MAX))
    return S


@dataclass
class ScalarUpdate:
    """Diagnostics of one scalar update (filterpy style).

    Attributes
    ----------
    H : ndarray, shape (9,)
        Measurement Jacobian row; only the position entries are nonzero for UWB.
    y : float
        Innovation ``z - h(x)``.
    R : float
        Measurement noise variance.
    PHT : ndarray, shape (9,)
        ``P H^T``.
    S : float
        Innovation variance ``H P H^T + R``.
    mahalanobis : float
        ``|y| / sqrt(S)``.
    K : ndarray, shape (9,)
        Kalman gain ``P H^T / S`` (zero until applied).
    """

    H: np.ndarray
    y: float
    R: float
    PHT: np.ndarray
    S: float
    mahalanobis: float
    K: np.ndarray = field(default_factory=lambda: np.zeros(N))


@dataclass
class ErrorStateEkf:
    """The filter state.

    Attributes
    ----------
    x : ndarray, shape (9,)
        Error state: position (world), velocity (body), attitude error.
    q : ndarray, shape (4,)
        Attitude quaternion (w, x, y, z), body -> world.
    R : ndarray, shape (3, 3)
        Rotation matrix of ``q``.
    P : ndarray, shape (9, 9)
        Covariance of the error state.
    acc_sum, gyro_sum : ndarray, shape (3,)
        IMU samples summed since the last prediction (``imu_count`` of them).
    t_us : int or None
        IMU mode: time of the last prediction; UWB-only mode: state time. None until set.
    """

    x: np.ndarray
    q: np.ndarray
    R: np.ndarray
    P: np.ndarray
    acc_sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    imu_count: int = 0
    t_us: int | None = None

    @classmethod
    def initial(cls, pos: np.ndarray, std_xy: float, std_z: float) -> "ErrorStateEkf":
        """Filter at ``pos`` (3,), at rest, level, with the diagonal initial covariance."""
        x = np.zeros(N)
        x[POS] = pos
        q = np.array([1.0, 0.0, 0.0, 0.0])
        var = [std_xy**2, std_xy**2, std_z**2] + [INIT_STD_VEL**2] * 3 + [INIT_STD_ATT**2] * 3
        # clamped like every other covariance (as ekf_init does): a huge init std stays bounded
        return cls(x=x, q=q, R=quat_to_rot(q), P=sym_clamp(np.diag(var)))

    # ------------------------------------------------------------------------------- prediction
    def imu_sample(self, t_us: int, acc: np.ndarray, gyro: np.ndarray, acc_xy: float, acc_z: float) -> bool:
        """Accumulate one IMU sample; predict with the averages every >= 10 ms. True if predicted.

        The first sample only sets the prediction time.
        """
        if self.t_us is None:
            self.t_us = t_us
            return False
        self.acc_sum += acc
        self.gyro_sum += gyro
        self.imu_count += 1
        if t_us - self.t_us >= PREDICT_INTERVAL_US:
            dt = (t_us - self.t_us) * 1e-6
            self.predict_imu(self.acc_sum / self.imu_count, self.gyro_sum / self.imu_count, dt, acc_xy, acc_z)
            self.acc_sum = np.zeros(3)
            self.gyro_sum = np.zeros(3)
            self.imu_count = 0
            self.t_us = t_us
            return True
        return False

    def transition_imu(self, gyro: np.ndarray, dt: float) -> np.ndarray:
        """Linearised transition ``A`` (9, 9) of the IMU-mode error dynamics over ``dt``.

        Blocks: position <- velocity ``R dt``; position <- attitude ``-R [v]x dt``;
        velocity <- velocity ``I - [w]x dt``; velocity <- attitude ``-g [R^T e3]x dt``;
        attitude <- attitude: second-order rotation with half-angles ``w dt / 2``.
        """
        R, v = self.R, self.x[VEL]
        A = np.eye(N)
        A[POS, VEL] = R * dt
        A[POS, ATT] = -R @ skew(v) * dt
        A[VEL, VEL] = np.eye(3) - skew(gyro) * dt
        A[VEL, ATT] = -GRAVITY * skew(R[2, :]) * dt
        A[ATT, ATT] = attitude_block(0.5 * gyro * dt)
        return A

    def predict_imu(self, acc: np.ndarray, gyro: np.ndarray, dt: float, acc_xy: float, acc_z: float) -> None:
        """One IMU-mode prediction with mean specific force ``acc`` (3,) and body rates ``gyro`` (3,)."""
        R = self.R
        A = self.transition_imu(gyro, dt)
        P = A @ self.P @ A.T
        Sa = np.diag([acc_xy**2, acc_xy**2, acc_z**2])
        P[POS, POS] += R @ Sa @ R.T * dt**3 / 3
        P[POS, VEL] += R @ Sa * dt**2 / 2
        P[VEL, POS] += (R @ Sa).T * dt**2 / 2
        P[VEL, VEL] += Sa * dt
        P[ATT, ATT] += np.diag([GYRO_NOISE_RP**2, GYRO_NOISE_RP**2, GYRO_NOISE_YAW**2]) * dt
        # Nominal state: p_dot = R v, v_dot = f - w x v - g R^T e3, q_dot = q (x) (0, w/2).
        v = self.x[VEL].copy()
        self.x[POS] += R @ (v * dt + acc * dt * dt / 2) - np.array([0.0, 0.0, GRAVITY * dt * dt / 2])
        self.x[VEL] = v + dt * (acc - np.cross(gyro, v) - GRAVITY * R[2, :])
        self.q = quat_rotate_body(self.q, gyro * dt)
        self.R = quat_to_rot(self.q)
        self.P = sym_clamp(P)

    def predict_cv(self, q_acc: float, dt: float) -> None:
        """Constant-velocity prediction ``p += v dt``, ``P = A P A^T + Q`` (UWB-only mode)."""
        A = np.eye(N)
        A[POS, VEL] = np.eye(3) * dt
        self.x = A @ self.x
        P = A @ self.P @ A.T
        q2 = q_acc * q_acc
        P[POS, POS] += np.eye(3) * q2 * dt**3 / 3
        P[POS, VEL] += np.eye(3) * q2 * dt**2 / 2
        P[VEL, POS] += np.eye(3) * q2 * dt**2 / 2
        P[VEL, VEL] += np.eye(3) * q2 * dt
        self.P = sym_clamp(P)

    # --------------------------------------------------------------------------------- update
    def prepare(self, h3: np.ndarray, y: float, r_var: float) -> ScalarUpdate:
        """Innovation statistics for ``H = [h3, 0 ... 0]`` before deciding to update."""
        H = np.zeros(N)
        H[POS] = h3
        PHT = self.P @ H
        S = float(H @ PHT + r_var)
        return ScalarUpdate(H=H, y=float(y), R=float(r_var), PHT=PHT, S=S, mahalanobis=abs(y) / np.sqrt(S))

    def apply(self, u: ScalarUpdate) -> None:
        """Correct the state and update P in Joseph form.

        ``P = (I - K H) P (I - K H)^T + K R K^T`` keeps P symmetric positive semi-definite for any
        gain, unlike ``(I - K H) P``.
        """
        u.K = u.PHT / u.S
        self.x = self.x + u.K * u.y
        IKH = np.eye(N) - np.outer(u.K, u.H)
        self.P = sym_clamp(IKH @ self.P @ IKH.T + u.R * np.outer(u.K, u.K))

    def finalize(self) -> None:
        """Move the attitude error into ``q``, rotate P accordingly, zero the attitude error."""
        v = self.x[ATT].copy()
        if np.all(np.abs(v) < ATT_ERR_MAX) and np.any(v != 0.0):
            self.q = quat_rotate_body(self.q, v)
            self.R = quat_to_rot(self.q)
            A = np.eye(N)
            A[ATT, ATT] = attitude_block(0.5 * v)
            self.P = sym_clamp(A @ self.P @ A.T)
        self.x[ATT] = 0.0

    def hold_at_rest(self) -> None:
        """A vehicle at rest (after a touchdown; UWB-only: on the floor): velocity zero and known (P_MIN), its
        correlations dropped, the position's covariance kept (ekf_core.c ekf_hold_at_rest)."""
        self.x[VEL] = 0.0
        self.P[VEL, :] = 0.0
        self.P[:, VEL] = 0.0
        self.P[VEL, VEL] = np.eye(3) * P_MIN

    def is_finite(self) -> bool:
        """True if the state, ``q`` and the diagonal of P are finite."""
        return bool(np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.q))
                    and np.all(np.isfinite(np.diagonal(self.P))))

    # ---------------------------------------------------------------------------- externalise
    def velocity_world(self) -> np.ndarray:
        """World-frame velocity (3,) ``R v_body``."""
        return self.R @ self.x[VEL]

    def rpy(self) -> np.ndarray:
        """Roll, pitch, yaw (3,) [rad]."""
        return quat_to_rpy(self.q)
