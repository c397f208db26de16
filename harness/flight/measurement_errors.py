"""Measurement error models of the simulator, each parameterised in a dataclass (SimConfig).

UWB measured value = true value + pose-dependent bias + multipath/NLOS error + Gaussian noise, then
quantised to the DW1000 clock tick. Per measurement (TWR to anchor i, or TDoA of pair (A, B)):

* Range bias of the link tag <-> anchor i (`AntennaConfig`), a smooth function of the relative pose:
      b_i = o_i + k_bore (1 - u_a.x) + sum_k c_ik Y_k(u_a) + k_dough (u_t.z)^2 + k_elev u_t.z
            + sum_k t_k Y_k(u_t) + k_range (r - r_ref)     (+ twr_offset for TWR)
  u_a = unit vector to the tag in the anchor antenna frame (anchor orientation), u_t = unit vector to
  the anchor in the tag body frame (so roll/pitch/yaw matter), Y_k = the 8 real degree-1/2 harmonics
  (x, y, z, xy, xz, yz, x^2 - y^2, 3z^2 - 1)/norm. o_i and c_ik are per anchor, t_k belong to the one
  tag; they are drawn from `hardware_seed` (the same radios in every flight, whatever the flight seed),
  so a network trained on one set of flights meets the same biases in the next. k_bore: signal drops
  off the anchor's boresight; k_dough: the tag's doughnut antenna is weak towards its axis; lower power
  -> later first-path detection -> positive bias.
  Everything is a smooth function of (anchor - tag) and the tag attitude: the features the firmware's
  network sees (the anchor identity is implied by dp because anchors sit at the arena's vertices).
* TDoA bias of pair (A, B): b_B - b_A + o_AB + k_pair (u_t.z of B - u_t.z of A): the two range biases
  plus the pair's own term (antenna-delay/clock calibration residual o_AB = -o_BA, per pair from
  `hardware_seed`, and an attitude-dependent term).
* Multipath/NLOS (`NlosConfig`): with probability p = p_base + p_ground exp(-z / h_ground) a link gets
  a positive excess path, exponential with mean `mean_m` (rare, large; more frequent near the ground).
  A link whose line of sight crosses an obstacle box is, with probability p_block, delayed by
  block_delay_m plus an exponential with mean block_mean_m (penetration: persistent while blocked).
  For TDoA the excesses of the two links enter with their signs (B minus A).
* Gaussian noise: std `twr_std` for TWR, `tdoa_std` for TDoA (TDoA is noisier, as the paper observes).
* Clock quantisation: values are rounded to c / (499.2 MHz x 128) = 4.69 mm (DW1000 timestamp tick).
* IMU (`ImuConfig`): white noise per sample, a turn-on bias and a bias random walk, accelerometer and
  gyro, at 1 kHz.

Profiles: "los" (default; UTIL const1/const2-like line-of-sight arena) and "nlos" (const3-like: three
obstacle boxes in the arena, more multipath). `uwb-hil calibrate` prints these models next to the real data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Union

import numpy as np

from harness.errors import InputError
from harness.flight.data import KIND_TDOA, KIND_TWR
from harness.flight.trajectory import quat_to_rot

if TYPE_CHECKING:
    from harness.flight.arena import Arena

SPEED_OF_LIGHT = 299_792_458.0
DW1000_TICK_M = SPEED_OF_LIGHT / (499.2e6 * 128.0)   # 4.69 mm
N_HARMONICS = 8

#: Where random draws come from: one generator for everything (a whole flight, in the order the functions
#: below draw), or one generator per named segment (harness/flight/chunked.py: a flight built in time
#: slices draws each segment's numbers in pieces and gets exactly the whole flight's values).
RngSource = Union[np.random.Generator, Callable[[str], np.random.Generator]]


def _gen(rng: RngSource, segment: str) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else rng(segment)


#: (segment, numpy method, draws per item), in the order uwb_errors / apply_imu_errors draw them
def uwb_draw_layout(kind: int) -> list[tuple[str, str, int]]:
    links = ("a",) if kind == KIND_TWR else ("a", "b")
    out = [(f"{k}.{name}", method, 1) for k in links
           for name, method in (("multipath", "random"), ("delayed", "random"), ("multipath_m", "exponential"),
                                ("block_m", "exponential"))]
    return out + [("noise", "normal", 1)]


IMU_DRAW_LAYOUT = [(f"{sensor}.{name}", "normal", per) for sensor in ("acc", "gyro")
                   for name, per in (("bias0", 0), ("rw", 3), ("white", 3))]   # bias0: 3 draws in all


@dataclass(frozen=True)
class AntennaConfig:
    """Pose-dependent range bias (see module doc). Lengths in metres."""

    hardware_seed: int = 2024
    anchor_offset_std: float = 0.02     # o_i
    anchor_pattern_std: float = 0.010   # c_ik, per harmonic
    boresight_k: float = 0.05           # k_bore
    tag_pattern_std: float = 0.008      # t_k, per harmonic
    doughnut_k: float = 0.08            # k_dough
    tag_elev_k: float = -0.06           # k_elev: anchor above the tag's horizon -> shorter (seen in rcv_twr)
    range_k: float = 0.006              # k_range [m per m]
    range_ref: float = 4.5              # r_ref [m]
    pair_offset_std: float = 0.025      # o_AB (TDoA only)
    pair_att_k: float = 0.02            # k_pair (TDoA only)


@dataclass(frozen=True)
class NlosConfig:
    """Multipath / non-line-of-sight errors (rare, large, positive on a link)."""

    p_base: float = 0.0005
    p_ground: float = 0.01
    h_ground: float = 0.2          # [m] e-folding height of the ground effect
    mean_m: float = 0.3            # exponential mean of the multipath excess [m]
    p_block: float = 0.0           # probability that a link whose line of sight crosses an obstacle is delayed
    block_delay_m: float = 0.0     # fixed extra path of a delayed blocked link [m]
    block_mean_m: float = 0.1      # plus an exponential with this mean [m]


@dataclass(frozen=True)
class ImuConfig:
    """Per-sample white noise (1 kHz), turn-on bias std, bias random walk [unit / sqrt(s)]."""

    acc_noise: float = 0.04        # m/s^2
    gyro_noise: float = 0.005      # rad/s
    acc_bias: float = 0.02         # m/s^2
    gyro_bias: float = 0.002       # rad/s
    acc_bias_rw: float = 0.002     # m/s^2 / sqrt(s)
    gyro_bias_rw: float = 0.0002   # rad/s / sqrt(s)


@dataclass(frozen=True)
class SimConfig:
    name: str = "los"
    antenna: AntennaConfig = field(default_factory=AntennaConfig)
    nlos: NlosConfig = field(default_factory=NlosConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    twr_std: float = 0.04          # [m] Gaussian noise of a TWR range
    tdoa_std: float = 0.055        # [m] Gaussian noise of a TDoA value
    twr_offset: float = 0.0        # [m] constant TWR offset (antenna-delay residual; rcv_twr radios: ~0.25)
    quantum_m: float = DW1000_TICK_M
    obstacles: bool = False        # place the NLOS boxes (harness/flight/arena.py) in the arena
    schedule_jitter: float = 0.1   # measurement time jitter as a fraction of the period


PROFILES = ("los", "nlos")


def sim_config(profile: str = "los") -> SimConfig:
    """The named error profile."""
    if profile == "los":
        return SimConfig()
    if profile == "nlos":
        return SimConfig(name="nlos", nlos=NlosConfig(p_base=0.005, p_ground=0.02, mean_m=0.3, p_block=1.0,
                                                      block_delay_m=0.15, block_mean_m=0.15),
                         tdoa_std=0.06, twr_std=0.045, obstacles=True)
    raise InputError(f"unknown simulator profile {profile!r}; choose one of {', '.join(PROFILES)}")


# --------------------------------------------------------------------------------- bias model
def harmonics(u: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors -> (N, 8) real harmonics of degree 1 and 2 (unit RMS over the sphere)."""
    x, y, z = u[:, 0], u[:, 1], u[:, 2]
    s3 = np.sqrt(3.0)
    s15 = np.sqrt(15.0)
    return np.stack([s3 * x, s3 * y, s3 * z, s15 * x * y, s15 * x * z, s15 * y * z,
                     0.5 * s15 * (x * x - y * y), 0.5 * np.sqrt(5.0) * (3 * z * z - 1)], axis=1)


@dataclass(frozen=True)
class HardwareParams:
    """The radios' fixed parameters, drawn from AntennaConfig.hardware_seed."""

    anchor_offset: dict[int, float]
    anchor_coef: dict[int, np.ndarray]
    tag_coef: np.ndarray

    def pair_offset(self, a: int, b: int, cfg: AntennaConfig) -> float:
        lo, hi = (a, b) if a < b else (b, a)
        rng = np.random.default_rng(np.random.SeedSequence([cfg.hardware_seed, 2, lo, hi]))
        v = float(rng.normal(0.0, cfg.pair_offset_std))
        return v if a < b else -v


def hardware_params(cfg: AntennaConfig, anchor_ids: np.ndarray) -> HardwareParams:
    off: dict[int, float] = {}
    coef: dict[int, np.ndarray] = {}
    for i in anchor_ids:
        rng = np.random.default_rng(np.random.SeedSequence([cfg.hardware_seed, 1, int(i)]))
        off[int(i)] = float(rng.normal(0.0, cfg.anchor_offset_std))
        coef[int(i)] = rng.normal(0.0, cfg.anchor_pattern_std, size=N_HARMONICS)
    trng = np.random.default_rng(np.random.SeedSequence([cfg.hardware_seed, 0]))
    return HardwareParams(off, coef, trng.normal(0.0, cfg.tag_pattern_std, size=N_HARMONICS))


def link_directions(anchor_pos: np.ndarray, anchor_quat: np.ndarray, tag_pos: np.ndarray,
                    tag_quat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u_a (tag seen in the anchor antenna frame), u_t (anchor seen in the tag body frame), range."""
    d = tag_pos - anchor_pos
    r = np.linalg.norm(d, axis=1)
    dw = d / np.maximum(r, 1e-9)[:, None]
    ra = quat_to_rot(anchor_quat)
    rt = quat_to_rot(tag_quat)
    u_a = np.einsum("nji,nj->ni", ra, dw)
    u_t = np.einsum("nji,nj->ni", rt, -dw)
    return u_a, u_t, r


def azimuth_elevation(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.arctan2(u[:, 1], u[:, 0]), np.arcsin(np.clip(u[:, 2], -1.0, 1.0))


def range_bias(cfg: AntennaConfig, hw: HardwareParams, anchor_ids: np.ndarray, anchor_pos: np.ndarray,
               anchor_quat: np.ndarray, tag_pos: np.ndarray, tag_quat: np.ndarray) -> np.ndarray:
    """Pose-dependent bias b_i of each link (module doc)."""
    u_a, u_t, r = link_directions(anchor_pos, anchor_quat, tag_pos, tag_quat)
    coef = np.stack([hw.anchor_coef[int(i)] for i in anchor_ids]) if len(anchor_ids) else np.zeros((0, 8))
    off = np.array([hw.anchor_offset[int(i)] for i in anchor_ids])
    return (off + cfg.boresight_k * (1.0 - u_a[:, 0]) + np.sum(coef * harmonics(u_a), axis=1)
            + cfg.doughnut_k * u_t[:, 2] ** 2 + cfg.tag_elev_k * u_t[:, 2] + harmonics(u_t) @ hw.tag_coef + cfg.range_k * (r - cfg.range_ref))


@dataclass(frozen=True)
class UwbErrors:
    bias: np.ndarray      # pose-dependent (learnable) part
    nlos: np.ndarray      # multipath / NLOS part (0 for most measurements)
    noise: np.ndarray     # Gaussian noise
    total: np.ndarray     # bias + nlos + noise, quantised value minus true value
    nlos_flag: np.ndarray  # bool: a multipath event hit this measurement


def _link_nlos(cfg: NlosConfig, arena: Arena, anchor_pos: np.ndarray, tag_pos: np.ndarray,
               rng: RngSource, link: str = "a") -> tuple[np.ndarray, np.ndarray]:
    """Excess path of each link: multipath events (rare, more likely near the ground) and obstacle
    penetration delays (a blocked line of sight: a fixed delay plus an exponential spread)."""
    n = tag_pos.shape[0]
    blocked = arena.blocked(tag_pos, anchor_pos) if arena.boxes else np.zeros(n, dtype=bool)
    p = cfg.p_base + cfg.p_ground * np.exp(-np.maximum(tag_pos[:, 2], 0.0) / cfg.h_ground)
    multipath = _gen(rng, f"{link}.multipath").random(n) < np.clip(p, 0.0, 1.0)
    delayed = blocked & (_gen(rng, f"{link}.delayed").random(n) < cfg.p_block)
    excess = (np.where(multipath, _gen(rng, f"{link}.multipath_m").exponential(cfg.mean_m, size=n), 0.0)
              + np.where(delayed, cfg.block_delay_m + _gen(rng, f"{link}.block_m").exponential(cfg.block_mean_m,
                                                                                           size=n), 0.0))
    return excess, multipath | delayed


def uwb_errors(cfg: SimConfig, kind: int, arena: Arena, tag_pos: np.ndarray, tag_quat: np.ndarray,
               a_ids: np.ndarray, b_ids: np.ndarray, rng: RngSource) -> UwbErrors:
    """Errors of each measurement (TWR: link to anchor a; TDoA: value d_B - d_A)."""
    anchors = arena.anchors
    if anchors.orientations is None:
        raise InputError("the realistic error model needs anchor orientations (Anchors.orientations)")
    hw = hardware_params(cfg.antenna, anchors.ids)
    idx = {int(i): k for k, i in enumerate(anchors.ids)}
    ka = np.array([idx[int(i)] for i in a_ids], dtype=np.int64)
    pa, qa = anchors.positions[ka], anchors.orientations[ka]
    ba = range_bias(cfg.antenna, hw, a_ids, pa, qa, tag_pos, tag_quat)
    na, ha = _link_nlos(cfg.nlos, arena, pa, tag_pos, rng, "a")
    n = tag_pos.shape[0]
    if kind == KIND_TWR:
        bias, nlos, flag = ba + cfg.twr_offset, na, ha
        noise = _gen(rng, "noise").normal(0.0, cfg.twr_std, size=n)
    elif kind == KIND_TDOA:
        kb = np.array([idx[int(i)] for i in b_ids], dtype=np.int64)
        pb, qb = anchors.positions[kb], anchors.orientations[kb]
        bb = range_bias(cfg.antenna, hw, b_ids, pb, qb, tag_pos, tag_quat)
        nb, hb = _link_nlos(cfg.nlos, arena, pb, tag_pos, rng, "b")
        _, ut_a, _ = link_directions(pa, qa, tag_pos, tag_quat)
        _, ut_b, _ = link_directions(pb, qb, tag_pos, tag_quat)
        pair = np.zeros(n)
        for a, b in set(zip(a_ids.tolist(), b_ids.tolist())):
            pair[(a_ids == a) & (b_ids == b)] = hw.pair_offset(a, b, cfg.antenna)
        bias = bb - ba + pair + cfg.antenna.pair_att_k * (ut_b[:, 2] - ut_a[:, 2])
        nlos, flag = nb - na, ha | hb
        noise = _gen(rng, "noise").normal(0.0, cfg.tdoa_std, size=n)
    else:
        raise ValueError(f"unknown measurement kind {kind}")
    raw = bias + nlos + noise
    return UwbErrors(bias=bias, nlos=nlos, noise=noise, total=raw, nlos_flag=flag)


def quantise(value: np.ndarray, quantum: float) -> np.ndarray:
    return np.round(value / quantum) * quantum if quantum > 0 else value


# --------------------------------------------------------------------------------------- IMU
def apply_imu_errors(acc: np.ndarray, gyro: np.ndarray, dt: float, cfg: ImuConfig,
                     rng: RngSource) -> tuple[np.ndarray, np.ndarray]:
    """Measured (specific force, rate) = true + turn-on bias + random-walk bias + white noise."""
    out_acc, out_gyro, _ = imu_errors_continued(acc, gyro, dt, cfg, rng, None)
    return out_acc, out_gyro


#: per sensor: (turn-on bias (1, 3), random walk so far (1, 3)) after the previous slice
ImuCarry = dict[str, tuple[np.ndarray, np.ndarray]]


def imu_errors_continued(acc: np.ndarray, gyro: np.ndarray, dt: float, cfg: ImuConfig, rng: RngSource,
                         carry: ImuCarry | None) -> tuple[np.ndarray, np.ndarray, ImuCarry]:
    """apply_imu_errors on one time slice of a longer flight (`carry` from the previous slice, None for
    the first): the bias random walk continues summing from where it was, in the same order."""
    n = acc.shape[0]
    out = []
    new_carry: ImuCarry = {}
    for sensor, true, noise, bias0, rw in (("acc", acc, cfg.acc_noise, cfg.acc_bias, cfg.acc_bias_rw),
                                           ("gyro", gyro, cfg.gyro_noise, cfg.gyro_bias, cfg.gyro_bias_rw)):
        if carry is None:
            b0, walked = _gen(rng, f"{sensor}.bias0").normal(0.0, bias0, size=(1, 3)), np.zeros((1, 3))
        else:
            b0, walked = carry[sensor]
        steps = _gen(rng, f"{sensor}.rw").normal(0.0, rw * np.sqrt(dt), size=(n, 3))
        walk = np.cumsum(np.concatenate([walked, steps]), axis=0)[1:]     # sequential sums, as one cumsum
        out.append(true + (b0 + walk) + _gen(rng, f"{sensor}.white").normal(0.0, noise, size=(n, 3)))
        new_carry[sensor] = (b0, walk[-1:].copy() if n else walked)
    return out[0], out[1], new_carry


__all__ = ["AntennaConfig", "NlosConfig", "ImuConfig", "SimConfig", "PROFILES", "sim_config", "range_bias",
           "hardware_params", "uwb_errors", "apply_imu_errors", "imu_errors_continued", "uwb_draw_layout",
           "IMU_DRAW_LAYOUT", "RngSource", "quantise", "link_directions",
           "azimuth_elevation", "harmonics", "DW1000_TICK_M"]
