"""The per-measurement pipeline (twin of firmware_sim/core/estimator.c).

Order per UWB measurement (docs/ARCHITECTURE.md): [UWB-only: constant-velocity prediction] ->
measurement model -> bias network -> kinematic gate -> chi-square gate -> Joseph update ->
finalize -> supervisor. HEIGHT pseudo-measurements (planar mode) are scalar updates of z.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from harness.config import (MODE_IMU_THRUST, MODE_UWB_ONLY, STAGE_BIAS_NN, STAGE_BIAS_STATES, STAGE_CHI2_GATE, STAGE_KINEMATIC_GATE,
                            STAGE_NN_MONITOR, STAGE_NN_STD, STAGE_ROBUST_UPDATE, EstimatorConfig)
from harness.errors import InputError
from harness.flight.data import Source
from harness.kinds import MeasInput, MeasurementKind, kind_of
from harness.twin import gates, supervisor
from harness.twin.anchor_table import AnchorTable
from harness.twin.bias_states import BiasStates
from harness.twin.ekf import POS, ErrorStateEkf
from harness.twin.features import features, ood_fade
from harness.twin.nn_monitor import NnMonitor
from harness.twin.takeoff import TakeoffDetector
from harness.twin.supervisor import (FLAG_COVARIANCE, FLAG_GAP_RESTART, FLAG_NON_FINITE,  # noqa: F401 (all flags here)
                                     FLAG_OUT_OF_BOX, FLAG_SPEED)
from protocol.messages import MAX_ANCHORS as PROTOCOL_MAX_ANCHORS
from protocol.messages import ErrorCode, MeasKind, ResultFlag, Status

if TYPE_CHECKING:
    from harness.flight.data import Flight

MAX_ANCHORS = PROTOCOL_MAX_ANCHORS     # slots of the estimator's anchor table (any 8-bit id)
#: HEIGHT std bound [m] (estimator.c EST_MAX_HEIGHT_STD): beyond it no information, and R could overflow
MAX_HEIGHT_STD = 1000.0

# protocol enum result_flag (supervisor events since the previous result), as plain ints
FLAG_DIVERGED = int(ResultFlag.DIVERGED)
FLAG_HEIGHT_FUSED = int(ResultFlag.HEIGHT_FUSED)
FLAG_NN_PAIR_OFF = int(ResultFlag.NN_PAIR_OFF)

# protocol enum status
ACCEPTED, REJECTED_KINEMATIC, REJECTED_CHI2 = int(Status.ACCEPTED), int(Status.REJECTED_KINEMATIC), int(Status.REJECTED_CHI2)
REJECTED_GEOMETRY, REJECTED_BASELINE = int(Status.REJECTED_GEOMETRY), int(Status.REJECTED_BASELINE)

# protocol enum error_code (what the firmware answers with ERROR)
ERR_UNKNOWN_ANCHOR, ERR_TIME_BACKWARDS = int(ErrorCode.UNKNOWN_ANCHOR), int(ErrorCode.TIME_BACKWARDS)
ERR_BAD_ANCHOR_ID = int(ErrorCode.BAD_ANCHOR_ID)
ERR_BAD_VALUE = int(ErrorCode.BAD_VALUE)


class TwinError(InputError):
    """A call the firmware would refuse with ERROR ``code``; the twin's state is unchanged."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


class BiasNet(Protocol):
    """One bias network: its input layout and ``predict(features (n_in,)) -> bias [m]``. A network
    with ``predict_with_std(features) -> (bias, std)`` also gives the measurement std (0: none)."""

    layout: int

    def predict(self, features: np.ndarray) -> float: ...


@dataclass(frozen=True)
class TwinState:
    """Externalised estimate: position (3,), world velocity (3,), quaternion (4,), P diagonal (9,)."""

    pos: np.ndarray
    vel: np.ndarray
    quat: np.ndarray
    var: np.ndarray


@dataclass(frozen=True)
class TwinResult:
    """Outcome of one measurement (the fields of the RESULT message, plus the Mahalanobis distance): status
    (ACCEPTED, REJECTED_KINEMATIC / CHI2 / GEOMETRY / BASELINE); innovation ``y = z - bias - h(x)`` before the
    update and its variance ``S = H P H^T + R`` (0 for geometry); bias, what was subtracted [m] (the network's
    correction plus the link's bias states); d_max, the kinematic bound [m], gate on or off; gain, the position
    rows of K (zero unless accepted); mahalanobis ``|y| / sqrt(S)``; pos (3,), vel (3,), quat (4,), var (9,),
    the estimate after the measurement; flags, supervisor events (FLAG_*) since the previous result."""

    status: int
    innovation: float
    innovation_var: float
    bias: float
    d_max: float
    gain: np.ndarray
    mahalanobis: float
    pos: np.ndarray
    vel: np.ndarray
    quat: np.ndarray
    var: np.ndarray
    flags: int = 0


class TwinEstimator:
    """Float64 reference of the firmware estimator.

    Parameters
    ----------
    config : EstimatorConfig
        Validated on construction (the firmware refuses the same values).
    anchors : dict[int, ndarray of shape (3,)]
        Anchor positions by id (any 8-bit id, at most MAX_ANCHORS).
    model : object, optional
        Bias networks as attributes ``twr`` and ``tdoa`` (either may be missing or None), each
        with ``layout`` and ``predict(features)``.
    """

    def __init__(self, config: EstimatorConfig, anchors: dict[int, np.ndarray], model: object | None = None) -> None:
        config.validate()
        self.config = config
        self.model = model
        self.table = AnchorTable(MAX_ANCHORS)   # keyed by id; per-anchor state by slot; anchors: id -> position
        self.anchors: dict[int, np.ndarray] = self.table.positions
        for anchor_id, pos in anchors.items():
            self.set_anchor(anchor_id, pos)
        self.predictions = 0
        self.imu_ignored = 0
        self.divergences = 0
        self.gap_restarts = 0   # restarts after a measurement gap (not divergences)
        self.nnmon = NnMonitor()
        self.kin = gates.KinematicGate()
        self.bstates = BiasStates()
        self.heights = 0
        self.baseline_rejects = 0   # TDoA answered REJECTED_BASELINE
        self._reset_filter()

    # ---------------------------------------------------------------------------- configuration
    def _reset_filter(self) -> None:
        c = self.config
        self.nnmon.reset()  # a new flight: every pair trusted again
        self.bstates.reset()
        self.takeoff = TakeoffDetector()
        self.last_good_pos = np.array([c.init_x, c.init_y, c.init_z], dtype=np.float64)
        self.ekf = ErrorStateEkf.initial(self.last_good_pos, c.init_std_xy, c.init_std_z)
        self.t_imu_us: int | None = None
        self.t_uwb_us: int | None = None
        self.t_height_us: int | None = None
        self.flags = 0
        self.kin.reset()

    def configure(self, config: EstimatorConfig, reset: bool = True) -> None:
        """Apply ``config``; ``reset`` re-initialises the filter and forgets the time references."""
        config.validate()
        self.config = config
        if reset:
            self._reset_filter()

    def set_anchor(self, anchor_id: int, pos: np.ndarray, radio_t_us: int | None = None) -> None:
        """A host position (stays), or one received over the radio at radio_t_us (LPP: valid 2 s; a host
        position of the id stays); any 8-bit id. TwinError(ERR_BAD_ANCHOR_ID): no slot left (estimator_anchors.c)."""
        ms = None if radio_t_us is None else (int(radio_t_us) // 1000) % (1 << 32)
        if not self.table.store(int(anchor_id), pos, ms):
            raise TwinError(ERR_BAD_ANCHOR_ID, f"anchor {anchor_id}: not an 8-bit id, or the table is full")

    def _slot(self, anchor_id: int, t_us: int) -> int:
        if (k := self.table.slot(anchor_id, t_us)) is None:
            raise TwinError(ERR_UNKNOWN_ANCHOR, f"unknown anchor {anchor_id}")
        return k

    # ----------------------------------------------------------------------------------- inputs
    def on_imu(self, t_us: int, acc: np.ndarray, gyro: np.ndarray) -> None:
        """One IMU sample (ignored, but time-checked, in UWB-only mode)."""
        t_us = int(t_us)
        if self.t_imu_us is not None and t_us < self.t_imu_us:
            raise TwinError(ERR_TIME_BACKWARDS, f"IMU time {t_us} < {self.t_imu_us}")
        self.t_imu_us = t_us
        c = self.config
        if self._imu_floor():   # UWB-only: R is the identity, the vehicle taken as level
            flying = self.takeoff.airborne
            if not self.takeoff.on_imu(t_us, float(acc[2]), float(self.ekf.R[2, 2])) and flying:
                self.ekf.hold_at_rest()   # a touchdown: the vehicle stopped
        if c.mode == MODE_UWB_ONLY:
            self.imu_ignored += 1
            return
        a = np.array(acc, dtype=np.float64)
        if c.mode == MODE_IMU_THRUST:   # quadrotor: the horizontal specific force taken as zero (estimator.c)
            a[:2] = 0.0
        if self.ekf.imu_sample(t_us, a, np.asarray(gyro, dtype=np.float64), c.proc_acc_xy, c.proc_acc_z):
            self.predictions += 1
            self._supervise()

    def _imu_floor(self) -> bool:   # the IMU tells when the vehicle sits on the floor (estimator.h estimator_floor_from_imu)
        return self.config.mode == MODE_IMU_THRUST or bool(self.config.floor_imu)

    def on_meas(self, kind: int, t_us: int, ids: tuple[int, ...], z: float) -> TwinResult:
        """One measurement of any kind (harness/kinds.py) naming anchors ``ids`` (A, or A and B, or none), as
        estimator_on_meas(). Per-anchor state (gates, monitor, bias states) is kept by slot; a kind without
        anchors (a sensor) is its own link (gates.SENSOR_SLOT)."""
        row = kind_of(kind)
        ids = tuple(int(i) for i in ids[:row.n_anchors]) * (2 if row.n_anchors == 1 else 1)
        slots = (self._slot(ids[0], t_us), self._slot(ids[1], t_us)) if ids else (gates.SENSOR_SLOT,) * 2
        self._check_uwb_time(int(t_us))
        a = self.anchors[ids[0]] if ids else None
        b = self.anchors[ids[1]] if row.n_anchors > 1 else None
        return self._process(row, int(t_us), slots, a, b, float(z))

    def on_twr(self, t_us: int, anchor: int, rng: float) -> TwinResult:
        """One two-way range to ``anchor``."""
        return self.on_meas(int(MeasKind.TWR), t_us, (anchor,), rng)

    def on_tdoa(self, t_us: int, a: int, b: int, diff: float) -> TwinResult:
        """One TDoA ``diff = d(tag, B) - d(tag, A)``."""
        return self.on_meas(int(MeasKind.TDOA), t_us, (a, b), diff)

    def state(self) -> TwinState:
        """The current estimate."""
        e = self.ekf
        return TwinState(pos=e.x[POS].copy(), vel=e.velocity_world(), quat=e.q.copy(), var=np.diagonal(e.P).copy())

    # -------------------------------------------------------------------------------- internals
    def _check_uwb_time(self, t_us: int) -> None:
        if self.t_uwb_us is not None and t_us < self.t_uwb_us:
            raise TwinError(ERR_TIME_BACKWARDS, f"UWB time {t_us} < {self.t_uwb_us}")

    def _supervise(self) -> None:
        """Restart at the last position that passed, with the initial covariance, if the state is not sane;
        after a measurement gap with half the bound as position variance (supervisor.c estimator_supervise)."""
        reason = supervisor.reason(self.ekf, self.config, self.anchors, self.t_uwb_us)
        if reason == 0:
            self.last_good_pos = self.ekf.x[POS].copy()
            return
        t_us = self.ekf.t_us
        c = self.config
        if reason == FLAG_GAP_RESTART:
            bound = supervisor.variance_bounds(self.config)
            self.ekf = ErrorStateEkf.initial(self.last_good_pos, float(np.sqrt(0.5 * bound[0])),
                                             float(np.sqrt(0.5 * bound[2])))
        else:
            self.ekf = ErrorStateEkf.initial(self.last_good_pos, c.init_std_xy, c.init_std_z)
        self.ekf.t_us = t_us
        if reason == FLAG_GAP_RESTART:   # the same restart, reported as a gap, not a divergence
            self.gap_restarts += 1
            self.flags |= FLAG_GAP_RESTART
            return
        self.divergences += 1
        self.flags |= FLAG_DIVERGED | reason

    def _predict_cv_to(self, t_us: int) -> None:
        """UWB-only: constant-velocity prediction to t_us (the first call only sets the state time)."""
        c, ekf = self.config, self.ekf
        if c.mode != MODE_UWB_ONLY:
            return
        if ekf.t_us is None:
            ekf.t_us = t_us
        elif t_us > ekf.t_us:
            ekf.predict_cv(c.proc_cv_acc, (t_us - ekf.t_us) * 1e-6)
            ekf.t_us = t_us
            self.predictions += 1
            self._supervise()

    def on_height(self, t_us: int, z: float, std: float) -> None:
        """A height pseudo-measurement: scalar update of z without gates (estimator_on_height)."""
        t_us = int(t_us)
        if not 0.0 < std <= MAX_HEIGHT_STD:
            raise TwinError(ERR_BAD_VALUE, f"height std must be in (0, {MAX_HEIGHT_STD:g}] m, got {std}")
        if self.t_height_us is not None and t_us < self.t_height_us:
            raise TwinError(ERR_TIME_BACKWARDS, f"HEIGHT time {t_us} < {self.t_height_us}")
        self.t_height_us = t_us
        self._predict_cv_to(t_us)
        ekf = self.ekf
        upd = ekf.prepare(np.array([0.0, 0.0, 1.0]), float(z) - float(ekf.x[2]), float(std) ** 2)
        ekf.apply(upd)
        ekf.finalize()
        self.heights += 1
        self.flags |= FLAG_HEIGHT_FUSED
        self._supervise()

    def _bias(self, net: BiasNet | None, anchor_a: np.ndarray | None, anchor_b: np.ndarray | None,
              cfg_std: float) -> tuple[float, float]:
        """(bias, predicted std or 0), as nn_bias() in estimator.c: faded to 0 outside the network's
        training range (when the network tells it, ``ood_excess``), the std moved to cfg_std alike."""
        c = self.config
        if not (c.stages & STAGE_BIAS_NN) or net is None or anchor_a is None or not (self.ekf.x[2] > c.nn_min_z):
            return 0.0, 0.0
        f = features(int(net.layout), self.ekf.x[POS], self.ekf.rpy(), anchor_a,
                     anchor_b if anchor_b is not None else anchor_a)
        if f.size == 0:
            return 0.0, 0.0
        excess = getattr(net, "ood_excess", None)
        fade = ood_fade(excess(f)) if excess is not None else 1.0
        if fade <= 0.0:
            return 0.0, 0.0
        with_std = getattr(net, "predict_with_std", None)
        bias, std = with_std(f) if with_std is not None else (net.predict(f), 0.0)
        if std > 0.0:
            std = fade * std + (1.0 - fade) * cfg_std
        return fade * float(bias), float(std)

    def _process(self, kind: MeasurementKind, t_us: int, ids: tuple[int, int], anchor_a: np.ndarray | None,
                 anchor_b: np.ndarray | None, z: float) -> TwinResult:
        c, ekf = self.config, self.ekf
        t_ref = ekf.t_us  # IMU mode: last prediction; UWB-only: state time before this prediction
        self._predict_cv_to(t_us)  # its supervisor check still sees the previous measurement's time (gap)
        self.t_uwb_us = t_us
        ekf = self.ekf
        if kind.floor_below > 0.0:   # a range to the floor: does the vehicle sit on it?
            self.takeoff.on_floor_range(t_us, np.float32(z) < np.float32(kind.floor_below))
        # on the floor: no re-opening, chi-square whatever the stages, UWB-only at rest (begin_measurement)
        on_floor = self.takeoff.on_floor(self._imu_floor(), t_us)
        if on_floor and c.mode == MODE_UWB_ONLY:
            self.ekf.hold_at_rest()
        dt = self.kin.window(t_us, ids, t_ref, c.gate_dt_min, widen=not on_floor)
        d_max = gates.kinematic_dmax(ekf.x[3:6], dt, kind.a_max(c))

        inp = MeasInput(ekf.x[POS], ekf.R, anchor_a, anchor_b, z, c)
        status, h, H3 = kind.model(inp)
        if status != ACCEPTED:
            self.baseline_rejects += status == REJECTED_BASELINE
            return self._result(status, 0.0, 0.0, 0.0, d_max, np.zeros(3), 0.0)

        net = kind.net(self.model)
        if net is not None and c.stages & STAGE_NN_MONITOR and not self.nnmon.enabled(*ids):
            net = None  # the monitor switched this pair's correction off
        bias, std_nn = self._bias(net, anchor_a, anchor_b, kind.meas_std(inp))
        # BIAS_STATES: the slowly varying rest, from the innovations of earlier measurements (links to anchors)
        states = bool(c.stages & STAGE_BIAS_STATES) and kind.n_anchors > 0
        b_st, var_st = self.bstates.predict(t_us, *ids) if states else (0.0, 0.0)
        y = (z - bias - b_st) - h

        # NN_STD: the network's own std of what it leaves, when it predicts one; else the configured std
        std = std_nn if (c.stages & STAGE_NN_STD and std_nn > 0.0) else kind.meas_std(inp)
        upd = ekf.prepare(H3, y, std * std + var_st)
        status = self._gate_status(kind, y, d_max, upd.S, on_floor)
        # the monitor compares what the filter sees with and without the correction, whatever the gates said
        if c.stages & STAGE_NN_MONITOR and bias != 0.0 and self.nnmon.observe(ids[0], ids[1], y, bias, upd.S):
            self.flags |= FLAG_NN_PAIR_OFF

        gain = np.zeros(3)
        if status == ACCEPTED:
            if c.stages & STAGE_ROBUST_UPDATE:  # M-estimation weight; the gates saw the nominal S
                r_w = gates.robust_r_var(y, upd.S - upd.R, upd.R)
                if r_w > upd.R:
                    upd = ekf.prepare(H3, y, r_w)
            ekf.apply(upd)
            ekf.finalize()
            if states:
                self.bstates.update(ids[0], ids[1], y, upd.S)
            self.kin.fused(t_us, ids)
            gain = upd.K[POS].copy()
            self._supervise()
        return self._result(status, y, upd.S, bias + b_st, d_max, gain, upd.mahalanobis)

    def _gate_status(self, kind: MeasurementKind, y: float, d_max: float, S: float, on_floor: bool = False) -> int:
        """The gates' verdict on innovation y (variance S): kinematic first, then chi-square, open for a link
        whose anchors had been rejected for long; on the floor the chi-square test applies whatever the stages
        (estimator.c gate_status)."""
        c = self.config
        if c.stages & STAGE_KINEMATIC_GATE and not gates.kinematic_pass(y, d_max, kind.gate_factor):
            return REJECTED_KINEMATIC
        if ((c.stages & STAGE_CHI2_GATE or on_floor) and not gates.chi2_pass(y, S, kind.chi2(c))
                and not self._chi2_reopened()):
            return REJECTED_CHI2
        return ACCEPTED

    def _chi2_reopened(self) -> bool:
        """The chi-square gate's lock-out guard for the measurement being processed."""
        return gates.chi2_reopened(self.kin.rejected_us)

    def _result(self, status: int, y: float, S: float, bias: float, d_max: float, gain: np.ndarray,
                mahalanobis: float) -> TwinResult:
        s = self.state()
        flags, self.flags = self.flags, 0
        return TwinResult(status=status, innovation=float(y), innovation_var=float(S), bias=float(bias),
                          d_max=float(d_max), gain=gain, mahalanobis=float(mahalanobis),
                          pos=s.pos, vel=s.vel, quat=s.quat, var=s.var, flags=flags)


def run_flight(flight: "Flight", config: EstimatorConfig, model: object | None = None) -> list[TwinResult]:
    """Feed ``flight.events()`` through a fresh twin; one TwinResult per UWB measurement (the auxiliary
    measurements are fused, their results not kept)."""
    twin = TwinEstimator(config, flight.anchors.as_dict(), model)
    u = flight.uwb
    ids = np.stack([u.anchor_a, u.anchor_b], axis=1)
    imu = flight.imu
    hgt = flight.height
    out: list[TwinResult] = []
    for t_us, source, i in flight.events():
        if source == Source.IMU:
            assert imu is not None
            twin.on_imu(t_us, imu.acc[i], imu.gyro[i])
        elif source == Source.HEIGHT:
            assert hgt is not None
            twin.on_height(t_us, float(hgt.z[i]), float(hgt.std))
        elif source == Source.AUX:
            assert flight.aux is not None
            a = flight.aux
            twin.on_meas(a.kind, t_us, (int(a.anchor_a[i]), int(a.anchor_b[i])), float(a.value[i]))
        else:
            out.append(twin.on_meas(u.kind, t_us, tuple(ids[i]), float(u.value[i])))
    return out
