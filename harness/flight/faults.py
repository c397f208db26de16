"""Sensor faults added to a Flight after simulation (or to a recording): NLOS outliers, IMU glitches, a
UWB outage, and an absurd IMU sample that makes the estimator diverge (to check that the divergence
guard fires and is reported). Seeded; what was injected is returned next to the new Flight."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from harness.flight.model import KIND_TWR, Flight, FlightError


@dataclass(frozen=True)
class FlightFaults:
    nlos_fraction: float = 0.0                  # share of UWB measurements given a positive NLOS bias
    nlos_bias_m: tuple[float, float] = (0.3, 1.5)   # uniform range of that bias (TDoA: random sign)
    imu_glitch_rate: float = 0.0                # share of IMU samples replaced by a spike
    imu_glitch_acc: float = 150.0               # spike amplitude bound [m/s^2] (16 g saturation ~157)
    imu_glitch_gyro: float = 20.0               # [rad/s]
    outage_start_s: float | None = None         # UWB outage: no measurement in [start, start + len)
    outage_len_s: float = 2.0
    diverge_at_s: float | None = None           # one IMU sample with a 1e30 m/s^2 acceleration
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.nlos_fraction <= 1.0 or not 0.0 <= self.imu_glitch_rate <= 1.0:
            raise ValueError("nlos_fraction and imu_glitch_rate must be within [0, 1]")
        lo, hi = self.nlos_bias_m
        if not 0.0 <= lo <= hi:
            raise ValueError(f"nlos_bias_m must be 0 <= lo <= hi, got {self.nlos_bias_m}")
        if self.outage_len_s < 0:
            raise ValueError("outage_len_s must be >= 0")


@dataclass
class InjectedFaults:
    nlos_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))   # into the NEW uwb stream
    imu_glitch_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    outage_us: tuple[int, int] | None = None
    outage_removed: int = 0
    diverge_imu_idx: int | None = None
    diverge_t_us: int | None = None


def inject(flight: Flight, faults: FlightFaults) -> tuple[Flight, InjectedFaults]:
    """A new Flight with the faults applied (the input is not modified)."""
    rng = np.random.default_rng(faults.seed)
    u = flight.uwb
    t0 = int(u.t_us[0]) if len(u) else 0
    out = InjectedFaults()
    keep = np.ones(len(u), bool)
    if faults.outage_start_s is not None:
        a = t0 + int(round(faults.outage_start_s * 1e6))
        b = a + int(round(faults.outage_len_s * 1e6))
        keep = (u.t_us < a) | (u.t_us >= b)
        out.outage_us = (a, b)
        out.outage_removed = int(np.count_nonzero(~keep))
    m_total = len(u)
    sliced = {n: getattr(u, n)[keep] for n in ("t_us", "anchor_a", "anchor_b", "value", "true_value")
              if isinstance(getattr(u, n), np.ndarray) and getattr(u, n).shape[:1] == (m_total,)}
    value = sliced["value"].astype(np.float64).copy()
    n_nlos = int(round(faults.nlos_fraction * len(value)))
    nlos = np.sort(rng.choice(len(value), n_nlos, replace=False)) if n_nlos else np.zeros(0, np.int64)
    bias = rng.uniform(*faults.nlos_bias_m, n_nlos)
    if u.kind != KIND_TWR:
        bias *= rng.choice([-1.0, 1.0], n_nlos)
    value[nlos] += bias
    sliced["value"] = value.astype(u.value.dtype)
    out.nlos_idx = nlos
    new_uwb = replace(u, **sliced)

    imu = flight.imu
    if imu is not None and (faults.imu_glitch_rate > 0 or faults.diverge_at_s is not None):
        acc = imu.acc.copy()
        gyro = imu.gyro.copy()
        n = len(imu)
        hits = np.nonzero(rng.random(n) < faults.imu_glitch_rate)[0]
        acc[hits] = rng.uniform(-faults.imu_glitch_acc, faults.imu_glitch_acc, (len(hits), 3))
        gyro[hits] = rng.uniform(-faults.imu_glitch_gyro, faults.imu_glitch_gyro, (len(hits), 3))
        out.imu_glitch_idx = hits
        if faults.diverge_at_s is not None:
            t_div = t0 + int(round(faults.diverge_at_s * 1e6))
            k = int(np.searchsorted(imu.t_us, t_div))
            if k >= n:
                raise FlightError(f"{flight.name}: diverge_at_s={faults.diverge_at_s} is after the last IMU sample")
            acc[k] = (1e30, -1e30, 1e30)         # finite, but no filter survives it
            out.diverge_imu_idx = k
            out.diverge_t_us = int(imu.t_us[k])
        imu = replace(imu, acc=acc, gyro=gyro)
    elif faults.diverge_at_s is not None:
        raise FlightError(f"{flight.name}: diverge_at_s needs IMU data")
    meta = dict(flight.meta)
    meta["faults"] = {"nlos": int(len(nlos)), "imu_glitches": int(len(out.imu_glitch_idx)),
                      "outage_removed": out.outage_removed, "diverge_t_us": out.diverge_t_us}
    return replace(flight, uwb=new_uwb, imu=imu, meta=meta), out
