"""The measurement kinds, defined once: one `MeasurementKind` row per kind of protocol enum meas_kind owns
its wire message, its anchors, its measurement model (the twin of core/mm_<kind>.c), the configuration
fields of its std, gate bounds, the network that corrects it and its input layouts, and its labels in
summaries and reports. Everything on the host that depends on the kind asks the row (`kind_of(code)`);
docs/ARCHITECTURE.md "Adding a measurement kind" is the recipe.

A model returns `(status, h, H3)`: ACCEPTED with the predicted measurement h and the position part H3 of
its Jacobian `H = [H3, 0 ... 0]`, or the RESULT status that stops the pipeline (REJECTED_GEOMETRY,
REJECTED_BASELINE), as the C row's model returns MM_OK or why not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from harness.errors import InputError
from protocol import messages as m
from protocol.messages import Layout, MeasKind, Stage, Status

#: Below this distance [m] a direction (p - a)/|p - a| is undefined.
MIN_DISTANCE = 1e-6

ModelOut = tuple[int, float, np.ndarray]


@dataclass(frozen=True)
class MeasInput:
    """What a model may read (core/mm_kinds.h mm_input_t): the estimate, the anchors, the value, the config."""

    p: np.ndarray                 # (3,) estimated position
    R: np.ndarray                 # (3, 3) estimated attitude, body -> world
    a: np.ndarray | None          # (3,) anchor A (None: a kind without anchors)
    b: np.ndarray | None          # (3,) anchor B (two-anchor kinds)
    z: float                      # the measurement
    config: Any                   # harness.config.EstimatorConfig


def _far_enough(d: float) -> bool:
    # Written as in C (`!(d >= min)` rejects): NaN counts as degenerate.
    return bool(d >= MIN_DISTANCE)


def twr(p: np.ndarray, anchor: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Range model ``h = |p - a|``, ``H3 = (p - a)^T / h``; None when the tag sits on the anchor."""
    d = np.asarray(p, dtype=np.float64) - np.asarray(anchor, dtype=np.float64)
    h = float(np.linalg.norm(d))
    if not _far_enough(h):
        return None
    return h, d / h


def tdoa(p: np.ndarray, anchor_a: np.ndarray, anchor_b: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Distance-difference model ``h = |p - b| - |p - a|``, ``H3 = (p-b)/|p-b| - (p-a)/|p-a|``; None when
    the tag sits on an anchor or the anchors coincide."""
    p = np.asarray(p, dtype=np.float64)
    a = np.asarray(anchor_a, dtype=np.float64)
    b = np.asarray(anchor_b, dtype=np.float64)
    da = float(np.linalg.norm(p - a))
    db = float(np.linalg.norm(p - b))
    dab = float(np.linalg.norm(b - a))
    if not (_far_enough(da) and _far_enough(db) and _far_enough(dab)):
        return None
    return db - da, (p - b) / db - (p - a) / da


def within_baseline(anchor_a: np.ndarray, anchor_b: np.ndarray, diff: float) -> bool:
    """|diff| below the distance between the two anchors, in float32 as the firmware (mm_tdoa.c): a
    Crazyflie's TDoA outlier filter discards the others before its update."""
    d = np.asarray(anchor_a, dtype=np.float32) - np.asarray(anchor_b, dtype=np.float32)
    f = np.float32(diff)
    return bool(f * f < d[0] * d[0] + d[1] * d[1] + d[2] * d[2])


def _outcome(model: tuple[float, np.ndarray] | None) -> ModelOut:
    if model is None:
        return int(Status.REJECTED_GEOMETRY), 0.0, np.zeros(3)
    return int(Status.ACCEPTED), model[0], model[1]


def _twr_model(x: MeasInput) -> ModelOut:
    assert x.a is not None
    return _outcome(twr(x.p, x.a))


def _tdoa_model(x: MeasInput) -> ModelOut:
    assert x.a is not None and x.b is not None
    out = _outcome(tdoa(x.p, x.a, x.b))
    if out[0] == Status.ACCEPTED and not within_baseline(x.a, x.b, x.z):
        return int(Status.REJECTED_BASELINE), 0.0, np.zeros(3)
    return out


def _twr_arm_model(x: MeasInput) -> ModelOut:
    """TWR from an antenna at lever arm l (config lever_x/y/z, body frame) of the body origin p the state
    estimates: h = |p + R l - a| (mm_twr_arm.c)."""
    assert x.a is not None
    lever = np.array([x.config.lever_x, x.config.lever_y, x.config.lever_z], dtype=np.float64)
    return _outcome(twr(np.asarray(x.p) + np.asarray(x.R) @ lever, x.a))


#: TOF validity and std model (mm_tof.c): tilt cosine floor, the ranger's range limit [m], and the std
#: std_tof (1 + exp(k (z - 2.5))), k = ln(80) / 1.5 (the Crazyflie's VL53L1x model)
TOF_MIN_COS, TOF_MAX_RANGE, TOF_STD_AT, TOF_STD_K = 0.1, 5.0, 2.5, 2.9213
#: a reading below this [m]: the vehicle sits on the floor (MM_TOF_FLOOR_BELOW)
TOF_FLOOR_BELOW = 0.1


def _tof_model(x: MeasInput) -> ModelOut:
    """A downward range to the floor z = 0 from a ranger at t = config tof_x/y/z (body frame) of the point the
    state estimates, along the body's -z axis: h = (p_z + (R t)_z) / R22, H3 = (0, 0, 1 / R22) (mm_tof.c).
    REJECTED_GEOMETRY when tipped (R22 <= 0.1) or the range is not one the ranger reports [0, 5 m)."""
    R = np.asarray(x.R, dtype=np.float64)
    t = np.array([x.config.tof_x, x.config.tof_y, x.config.tof_z], dtype=np.float64)
    c = float(R[2, 2])
    s_z = float(x.p[2]) + float(R[2] @ t)
    if not (c > TOF_MIN_COS and 0.0 <= x.z < TOF_MAX_RANGE and np.isfinite(s_z)):
        return int(Status.REJECTED_GEOMETRY), 0.0, np.zeros(3)
    return int(Status.ACCEPTED), s_z / c, np.array([0.0, 0.0, 1.0 / c])


def _tof_std(x: MeasInput) -> float:
    """The ranger's std at its measured range (mm_tof.c std_of)."""
    return float(x.config.std_tof) * (1.0 + float(np.exp(TOF_STD_K * (x.z - TOF_STD_AT))))


@dataclass(frozen=True)
class MeasurementKind:
    """One kind of measurement (a row of the table; its C twin is the row in core/mm_<key>.c)."""

    code: int                          # protocol enum meas_kind (RESULT.kind, UwbStream.kind)
    key: str                           # "twr": summaries' and reports' keys, the BiasModel attribute
    label: str                         # "TWR": tables and plots
    message: type                      # the wire message (protocol.messages)
    anchor_fields: tuple[str, ...]     # its anchor-id fields, A then B
    value_field: str                   # its measured-value field
    value_name: str                    # what the value is, in messages ("range")
    std_field: str                     # EstimatorConfig fields: the measurement std,
    chi2_field: str                    # the chi-square gate's threshold,
    a_max_field: str                   # the kinematic gate's acceleration bound
    gate_factor: float                 # the kinematic gate rejects |y| > gate_factor d_max
    model: Callable[[MeasInput], ModelOut]
    network: str | None = None         # the BiasModel attribute of the network that corrects it
    layouts: tuple[int, ...] = ()      # the network's input layouts (protocol enum layout)
    std_of: Callable[[MeasInput], float] | None = None   # the std of one measurement (None: std_field)
    floor_below: float = 0.0           # a range to the floor: below this [m] the vehicle sits on it (0: none)

    @property
    def n_anchors(self) -> int:
        return len(self.anchor_fields)

    @property
    def link(self) -> str:
        """What one link is: an anchor, a pair of them, or (no anchor) the sensor itself."""
        return ("sensor", "anchor", "pair")[self.n_anchors]

    def anchor_ids(self, uwb: Any) -> tuple[np.ndarray, ...]:
        """The anchor-id columns of a UwbStream its measurements use (A, or A and B)."""
        return (uwb.anchor_a, uwb.anchor_b)[:self.n_anchors]

    def link_keys(self, anchor_a: np.ndarray, anchor_b: np.ndarray) -> np.ndarray:
        """One integer per link (anchor A, or the pair A * 1000 + B)."""
        a = np.asarray(anchor_a, dtype=np.int64)
        return a if self.n_anchors == 1 else a * 1000 + np.asarray(anchor_b, dtype=np.int64)

    def wire_columns(self, uwb: Any) -> dict[str, np.ndarray]:
        """The message's columns for protocol.batch.encode_rows, from a UwbStream of this kind."""
        cols = {"t_us": uwb.t_us, self.value_field: uwb.value}
        cols.update(zip(self.anchor_fields, self.anchor_ids(uwb)))
        return cols

    def std(self, config: Any) -> float:
        return float(getattr(config, self.std_field))

    def meas_std(self, x: MeasInput) -> float:
        """The std to fuse measurement x with (before any network's): the kind's own, or the config field."""
        return self.std_of(x) if self.std_of is not None else self.std(x.config)

    def chi2(self, config: Any) -> float:
        return float(getattr(config, self.chi2_field))

    def a_max(self, config: Any) -> float:
        return float(getattr(config, self.a_max_field))

    def net(self, model: Any) -> Any:
        """This kind's network of a BiasModel (None without one)."""
        return getattr(model, self.network, None) if (model is not None and self.network) else None


#: the table: one row per kind (docs/ARCHITECTURE.md "Adding a measurement kind")
KINDS: Mapping[int, MeasurementKind] = {k.code: k for k in (
    MeasurementKind(int(MeasKind.TWR), "twr", "TWR", m.Twr, ("anchor_id",), "range", "range", "std_twr",
                    "chi2_twr", "a_max_twr", 1.0, _twr_model, "twr", (int(Layout.TWR_POSE), int(Layout.TWR_POS))),
    MeasurementKind(int(MeasKind.TDOA), "tdoa", "TDoA", m.Tdoa, ("anchor_a", "anchor_b"), "diff", "TDoA",
                    "std_tdoa", "chi2_tdoa", "a_max_tdoa", 2.0, _tdoa_model, "tdoa",
                    (int(Layout.TDOA_POSE), int(Layout.TDOA_POS))),
    MeasurementKind(int(MeasKind.TWR_ARM), "twr_arm", "TWR (lever arm)", m.TwrArm, ("anchor_id",), "range",
                    "range", "std_twr", "chi2_twr", "a_max_twr", 1.0, _twr_arm_model),
    MeasurementKind(int(MeasKind.TOF), "tof", "ToF height", m.Tof, (), "range", "range", "std_tof", "chi2_twr",
                    "a_max_twr", 1.0, _tof_model, std_of=_tof_std, floor_below=TOF_FLOOR_BELOW),
)}

#: the kinds' keys, in table order (summaries and reports keyed by kind)
KIND_KEYS: tuple[str, ...] = tuple(k.key for k in KINDS.values())


class UnknownKindError(InputError):
    """A measurement kind the table has no row for."""


def kind_of(code: int) -> MeasurementKind:
    """The row of a kind code (UwbStream.kind, RESULT.kind)."""
    try:
        return KINDS[int(code)]
    except KeyError:
        raise UnknownKindError(f"unknown measurement kind {code!r} (known: "
                               f"{', '.join(f'{k.code} {k.label}' for k in KINDS.values())})") from None


def kind_named(key: str) -> MeasurementKind:
    """The row of a kind key ("twr")."""
    for k in KINDS.values():
        if k.key == key:
            return k
    raise UnknownKindError(f"unknown measurement kind {key!r} (known: {', '.join(k.key for k in KINDS.values())})")


def check_network_present(network: str | None, stages: int, layouts: tuple[int, int], what: str) -> None:
    """Refuse a bias-network stage on measurements the device has no network for (`network` = "twr" / "tdoa",
    the kind's BiasModel attribute; `layouts` = the device's (TWR, TDoA) layouts from HELLO, 0 = none): the
    firmware would skip the correction and the figures, labelled with the network's stage, would be those of
    the stage without it."""
    if not stages & Stage.BIAS_NN or not network:
        return
    if dict(zip(("twr", "tdoa"), layouts)).get(network, 0) == 0:
        raise InputError(f"{what} corrects {network.upper()} measurements with the bias network, but the device "
                         f"has no {network.upper()} network (a model without one: give --model with a "
                         f"{network.upper()} network, or stages without nn)")
