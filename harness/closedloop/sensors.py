"""Sensors of the closed loop: UWB measurements and IMU samples produced from the TRUE vehicle state, one
control step at a time, with the simulator's calibrated error models (harness/flight/measurement_errors.py).

The simulator evaluates its models vectorised over a whole pre-computed flight; in the loop the true
state is known only step by step, where numpy's per-call overhead on a handful of rows dominates. So the
per-link bias b_i, the TDoA pair term and the multipath probability of measurement_errors are evaluated here in
scalar form, from the same HardwareParams (same hardware_seed: the same radios the bias network was
trained on). tests/device/test_closedloop.py checks the scalar bias against measurement_errors to 1e-9 m.

Schedule (as the simulator's): TWR round-robin over the anchors, TDoA2 consecutive pairs
(N-1, 0), (0, 1), ...; periodic at `rate_hz` with a uniform jitter of +-`schedule_jitter` periods.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harness.errors import UsageError
from harness.flight.arena import Arena
from harness.flight.measurement_errors import HardwareParams, ImuConfig, SimConfig, hardware_params
from harness.flight.data import KIND_TDOA, KIND_TWR

NOISE_KINDS = ("none", "gaussian", "realistic")
_S3, _S15, _S5 = math.sqrt(3.0), math.sqrt(15.0), math.sqrt(5.0)


def _harmonics(x: float, y: float, z: float) -> tuple[float, ...]:
    """The 8 real degree-1/2 harmonics of measurement_errors.harmonics, for one unit vector."""
    return (_S3 * x, _S3 * y, _S3 * z, _S15 * x * y, _S15 * x * z, _S15 * y * z,
            0.5 * _S15 * (x * x - y * y), 0.5 * _S5 * (3 * z * z - 1))


def _rot(q: tuple[float, float, float, float] | list[float]) -> tuple[float, ...]:
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


@dataclass(frozen=True)
class UwbSample:
    t_us: int
    anchor_a: int
    anchor_b: int          # -1 for TWR
    value: float           # measured [m]
    true_value: float
    nlos: bool


class LinkModel:
    """Scalar evaluation of measurement_errors's pose-dependent link bias and TDoA pair term."""

    def __init__(self, cfg: SimConfig, arena: Arena) -> None:
        anchors = arena.anchors
        if anchors.orientations is None:
            raise UsageError("the realistic error model needs anchor orientations (Anchors.orientations)")
        self.cfg = cfg
        self.hw: HardwareParams = hardware_params(cfg.antenna, anchors.ids)
        self.pos = {int(i): tuple(float(v) for v in anchors.positions[k]) for k, i in enumerate(anchors.ids)}
        self.rot = {int(i): _rot(tuple(anchors.orientations[k])) for k, i in enumerate(anchors.ids)}
        self.coef = {int(i): tuple(float(c) for c in self.hw.anchor_coef[int(i)]) for i in anchors.ids}
        self.tag_coef = tuple(float(c) for c in self.hw.tag_coef)
        ids = [int(i) for i in anchors.ids]
        self.pair = {(a, b): self.hw.pair_offset(a, b, cfg.antenna) for a in ids for b in ids if a != b}

    def link(self, anchor: int, tag: tuple[float, float, float], r_tag: tuple[float, ...]) -> tuple[float, float, float]:
        """(bias b_i, range, u_t.z) of the link tag <-> anchor; r_tag = tag rotation (row-major)."""
        a = self.pos[anchor]
        dx, dy, dz = tag[0] - a[0], tag[1] - a[1], tag[2] - a[2]
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        inv = 1.0 / max(r, 1e-9)
        dx, dy, dz = dx * inv, dy * inv, dz * inv
        ra = self.rot[anchor]
        # u_a = R_a^T dw (tag seen from the anchor), u_t = R_t^T (-dw) (anchor seen from the tag)
        uax = ra[0] * dx + ra[3] * dy + ra[6] * dz
        uay = ra[1] * dx + ra[4] * dy + ra[7] * dz
        uaz = ra[2] * dx + ra[5] * dy + ra[8] * dz
        rt = r_tag
        utx = -(rt[0] * dx + rt[3] * dy + rt[6] * dz)
        uty = -(rt[1] * dx + rt[4] * dy + rt[7] * dz)
        utz = -(rt[2] * dx + rt[5] * dy + rt[8] * dz)
        ant = self.cfg.antenna
        ha = _harmonics(uax, uay, uaz)
        ht = _harmonics(utx, uty, utz)
        c = self.coef[anchor]
        t = self.tag_coef
        b = (self.hw.anchor_offset[anchor] + ant.boresight_k * (1.0 - uax)
             + sum(c[k] * ha[k] for k in range(8)) + ant.doughnut_k * utz * utz + ant.tag_elev_k * utz
             + sum(t[k] * ht[k] for k in range(8)) + ant.range_k * (r - ant.range_ref))
        return b, r, utz

    def multipath_probability(self, tag: tuple[float, float, float]) -> float:
        """Probability of a multipath event on a link (more likely near the ground)."""
        n = self.cfg.nlos
        return min(1.0, max(0.0, n.p_base + n.p_ground * math.exp(-max(tag[2], 0.0) / n.h_ground)))

    def blocked(self, anchor: int, tag: tuple[float, float, float], arena: Arena) -> bool:
        """Does the line of sight tag -> anchor cross an obstacle box?"""
        return bool(arena.boxes) and bool(arena.blocked(np.array([tag]), np.array([self.pos[anchor]]))[0])


@dataclass(frozen=True)
class SensorConfig:
    mode: str = "tdoa"                 # "twr" | "tdoa" (TDoA2 consecutive pairs)
    noise: str = "realistic"           # "none" | "gaussian" | "realistic"
    noise_std: float = 0.1             # gaussian only [m]
    rate_hz: float | None = None       # UWB rate; None: 200 (TWR) / 400 (TDoA), as the simulator
    imu_noise: bool = True             # IMU errors (ImuConfig of the profile) unless noise == "none"

    def validate(self) -> None:
        if self.mode not in ("twr", "tdoa"):
            raise UsageError(f"sensor mode must be 'twr' or 'tdoa', got {self.mode!r}")
        if self.noise not in NOISE_KINDS:
            raise UsageError(f"noise must be one of {NOISE_KINDS}, got {self.noise!r}")
        rate = self.uwb_rate()
        if not 1.0 <= rate <= 5000.0:
            raise UsageError(f"UWB rate must be in [1, 5000] Hz, got {rate}")
        if not (self.noise_std >= 0.0 and math.isfinite(self.noise_std)):
            raise UsageError(f"noise_std must be >= 0, got {self.noise_std}")

    def uwb_rate(self) -> float:
        return float(self.rate_hz) if self.rate_hz is not None else (200.0 if self.mode == "twr" else 400.0)

    @property
    def kind(self) -> int:
        return KIND_TWR if self.mode == "twr" else KIND_TDOA


class Sensors:
    """Produces the measurements of one flight, step by step. Independent random streams per purpose
    (schedule, UWB errors, IMU errors), all from `seed`."""

    def __init__(self, cfg: SensorConfig, sim: SimConfig, arena: Arena, seed: int, imu_dt: float) -> None:
        cfg.validate()
        self.cfg = cfg
        self.sim = sim
        self.arena = arena
        self.ids = [int(i) for i in arena.anchors.ids]
        self.links = LinkModel(sim, arena) if cfg.noise == "realistic" else None
        ss = np.random.SeedSequence([seed, 0x5E45])
        r_sched, r_uwb, r_imu = (np.random.default_rng(s) for s in ss.spawn(3))
        self._r_sched, self._r_uwb, self._r_imu = r_sched, r_uwb, r_imu
        self.period_us = 1e6 / cfg.uwb_rate()
        self._k = 0                                  # index of the next measurement
        self._next_t = self._draw_time(0)
        # IMU: white noise given per 1 kHz sample; a sample at imu_dt averages 1 ms samples -> std / sqrt(n)
        imu: ImuConfig = sim.imu
        self.imu_dt = imu_dt
        on = cfg.imu_noise and cfg.noise != "none"
        scale = math.sqrt(1e-3 / imu_dt) if on else 0.0
        self._acc_w, self._gyro_w = imu.acc_noise * scale, imu.gyro_noise * scale
        self._acc_rw = imu.acc_bias_rw * math.sqrt(imu_dt) if on else 0.0
        self._gyro_rw = imu.gyro_bias_rw * math.sqrt(imu_dt) if on else 0.0
        self._acc_b = r_imu.normal(0.0, imu.acc_bias, 3) if on else np.zeros(3)
        self._gyro_b = r_imu.normal(0.0, imu.gyro_bias, 3) if on else np.zeros(3)
        self._on = on
        self.nlos_events = 0

    # ----------------------------------------------------------------------------------------- UWB
    def _draw_time(self, k: int) -> int:
        jitter = self.sim.schedule_jitter
        return int(round(self.period_us * (1 + k) + float(self._r_sched.uniform(-jitter, jitter)) * self.period_us))

    def due(self, t_end_us: int) -> list[tuple[int, int]]:
        """(index, time) of the measurements with time <= t_end_us not yet produced, in order."""
        out = []
        while self._next_t <= t_end_us:
            out.append((self._k, self._next_t))
            self._k += 1
            self._next_t = max(self._next_t, self._draw_time(self._k))  # jitter never reorders them
        return out

    def anchors_of(self, k: int) -> tuple[int, int]:
        n = len(self.ids)
        if self.cfg.mode == "twr":
            return self.ids[k % n], -1
        j = k % n
        return self.ids[(j - 1) % n], self.ids[j]

    def measure(self, k: int, t_us: int, tag: tuple[float, float, float],
                quat: tuple[float, float, float, float] | list[float]) -> UwbSample:
        """Measurement k at t_us from the true tag position and attitude."""
        a, b = self.anchors_of(k)
        pa = self.arena.anchors.position(a) if self.links is None else self.links.pos[a]
        da = math.dist(tag, tuple(pa))
        if b < 0:
            true = da
        else:
            pb = self.arena.anchors.position(b) if self.links is None else self.links.pos[b]
            true = math.dist(tag, tuple(pb)) - da
        nlos = False
        if self.cfg.noise == "none":
            value = true
        elif self.cfg.noise == "gaussian":
            value = true + float(self._r_uwb.normal(0.0, self.cfg.noise_std))
        else:
            value, nlos = self._realistic(a, b, true, tag, quat)
        self.nlos_events += nlos
        return UwbSample(t_us=t_us, anchor_a=a, anchor_b=b, value=value, true_value=true, nlos=nlos)

    def _link_nlos(self, anchor: int, tag: tuple[float, float, float]) -> float:
        """Excess path of one link: a multipath event, plus a penetration delay if an obstacle blocks it."""
        assert self.links is not None
        cfg = self.sim.nlos
        r = self._r_uwb
        excess = 0.0
        if float(r.random()) < self.links.multipath_probability(tag):
            excess += float(r.exponential(cfg.mean_m))
        if cfg.p_block > 0.0 and self.links.blocked(anchor, tag, self.arena) and float(r.random()) < cfg.p_block:
            excess += cfg.block_delay_m + float(r.exponential(cfg.block_mean_m))
        return excess

    def _realistic(self, a: int, b: int, true: float, tag: tuple[float, float, float],
                   quat: tuple[float, float, float, float] | list[float]) -> tuple[float, bool]:
        assert self.links is not None
        rt = _rot(quat)
        ba, _, uta = self.links.link(a, tag, rt)
        ea = self._link_nlos(a, tag)
        if b < 0:
            bias, nl = ba + self.sim.twr_offset, ea
            noise = float(self._r_uwb.normal(0.0, self.sim.twr_std))
            hit = ea != 0.0
        else:
            bb, _, utb = self.links.link(b, tag, rt)
            eb = self._link_nlos(b, tag)
            bias = bb - ba + self.links.pair[(a, b)] + self.sim.antenna.pair_att_k * (utb - uta)
            nl = eb - ea
            noise = float(self._r_uwb.normal(0.0, self.sim.tdoa_std))
            hit = ea != 0.0 or eb != 0.0
        value = true + bias + nl + noise
        q = self.sim.quantum_m
        if q > 0:
            value = round(value / q) * q
        return value, hit

    # ----------------------------------------------------------------------------------------- IMU
    def imu(self, specific_force: tuple[float, float, float], gyro: tuple[float, float, float]
            ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """One IMU sample (measured specific force, rate) from the true ones."""
        if not self._on:
            return specific_force, gyro
        r = self._r_imu
        self._acc_b = self._acc_b + r.normal(0.0, self._acc_rw, 3)
        self._gyro_b = self._gyro_b + r.normal(0.0, self._gyro_rw, 3)
        na = r.normal(0.0, self._acc_w, 3)
        ng = r.normal(0.0, self._gyro_w, 3)
        acc = tuple(float(specific_force[i] + self._acc_b[i] + na[i]) for i in range(3))
        gy = tuple(float(gyro[i] + self._gyro_b[i] + ng[i]) for i in range(3))
        return acc, gy  # type: ignore[return-value]
