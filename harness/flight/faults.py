"""Sensor faults added to a Flight after simulation (or to a recording): NLOS outliers, IMU glitches, a
UWB outage, and an absurd IMU sample that makes the estimator diverge (to check that the divergence
guard fires and is reported). Seeded; what was injected is returned next to the new Flight."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np

from harness.errors import UsageError
from harness.flight.chunked import IMU_RATE_HZ, SimPlan
from harness.flight.data import KIND_TWR, Flight, FlightError


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
            raise UsageError("nlos_fraction and imu_glitch_rate must be within [0, 1]")
        lo, hi = self.nlos_bias_m
        if not 0.0 <= lo <= hi:
            raise UsageError(f"nlos_bias_m must be 0 <= lo <= hi, got {self.nlos_bias_m}")
        if self.outage_len_s < 0:
            raise UsageError("outage_len_s must be >= 0")


@dataclass
class InjectedFaults:
    nlos_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))   # into the NEW uwb stream
    imu_glitch_idx: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    outage_us: tuple[int, int] | None = None
    outage_removed: int = 0
    diverge_imu_idx: int | None = None
    diverge_t_us: int | None = None


@dataclass
class FaultPlan:
    """What `inject` does to a flight, decided once from its timestamps (compact: indices and values), so
    it can be applied to the whole flight or to its consecutive slices (harness/flight/chunked.py) alike."""

    faults: FlightFaults
    injected: InjectedFaults
    keep_window: tuple[int, int] | None            # UWB measurements with a <= t < b are removed
    nlos_bias: np.ndarray                          # added to value[injected.nlos_idx]
    glitch_acc: np.ndarray                         # (len(imu_glitch_idx), 3)
    glitch_gyro: np.ndarray


def plan_faults(faults: FlightFaults, name: str, kind: int, uwb_t_us: np.ndarray,
                imu_t_us: np.ndarray | None) -> FaultPlan:
    """The faults for a flight with these timestamps (same draws, in the same order, as always)."""
    rng = np.random.default_rng(faults.seed)
    t0 = int(uwb_t_us[0]) if len(uwb_t_us) else 0
    out = InjectedFaults()
    window = None
    n_kept = len(uwb_t_us)
    if faults.outage_start_s is not None:
        a = t0 + int(round(faults.outage_start_s * 1e6))
        b = a + int(round(faults.outage_len_s * 1e6))
        window = (a, b)
        out.outage_us = window
        out.outage_removed = int(np.count_nonzero((uwb_t_us >= a) & (uwb_t_us < b)))
        n_kept -= out.outage_removed
    n_nlos = int(round(faults.nlos_fraction * n_kept))
    nlos = np.sort(rng.choice(n_kept, n_nlos, replace=False)) if n_nlos else np.zeros(0, np.int64)
    bias = rng.uniform(*faults.nlos_bias_m, n_nlos)
    if kind != KIND_TWR:
        bias *= rng.choice([-1.0, 1.0], n_nlos)
    out.nlos_idx = nlos
    g_acc, g_gyro = np.zeros((0, 3)), np.zeros((0, 3))
    if imu_t_us is not None and (faults.imu_glitch_rate > 0 or faults.diverge_at_s is not None):
        n = len(imu_t_us)
        hits = np.nonzero(rng.random(n) < faults.imu_glitch_rate)[0]
        g_acc = rng.uniform(-faults.imu_glitch_acc, faults.imu_glitch_acc, (len(hits), 3))
        g_gyro = rng.uniform(-faults.imu_glitch_gyro, faults.imu_glitch_gyro, (len(hits), 3))
        out.imu_glitch_idx = hits
        if faults.diverge_at_s is not None:
            t_div = t0 + int(round(faults.diverge_at_s * 1e6))
            k = int(np.searchsorted(imu_t_us, t_div))
            if k >= n:
                raise FlightError(f"{name}: diverge_at_s={faults.diverge_at_s} is after the last IMU sample")
            out.diverge_imu_idx = k
            out.diverge_t_us = int(imu_t_us[k])
    elif faults.diverge_at_s is not None:
        raise FlightError(f"{name}: diverge_at_s needs IMU data")
    return FaultPlan(faults, out, window, bias, g_acc, g_gyro)


def inject(flight: Flight, faults: FlightFaults) -> tuple[Flight, InjectedFaults]:
    """A new Flight with the faults applied (the input is not modified)."""
    plan = plan_faults(faults, flight.name, flight.uwb.kind, flight.uwb.t_us,
                       flight.imu.t_us if flight.imu is not None else None)
    new, _ = apply_faults(flight, plan, 0, 0)
    return new, plan.injected


def apply_faults(piece: Flight, plan: FaultPlan, kept_before: int, imu_before: int) -> tuple[Flight, int]:
    """`plan` applied to a slice whose first measurement follows `kept_before` measurements kept so far
    and whose first IMU sample is sample `imu_before` of the flight. Returns the slice and how many of
    its measurements were kept."""
    u = piece.uwb
    m_total = len(u)
    keep = np.ones(m_total, bool)
    if plan.keep_window is not None:
        a, b = plan.keep_window
        keep = (u.t_us < a) | (u.t_us >= b)
    sliced = {n: getattr(u, n)[keep] for n in ("t_us", "anchor_a", "anchor_b", "value", "true_value")
              if isinstance(getattr(u, n), np.ndarray) and getattr(u, n).shape[:1] == (m_total,)}
    value = sliced["value"].astype(np.float64).copy()
    inj = plan.injected
    lo, hi = np.searchsorted(inj.nlos_idx, [kept_before, kept_before + len(value)])
    value[inj.nlos_idx[lo:hi] - kept_before] += plan.nlos_bias[lo:hi]
    sliced["value"] = value.astype(u.value.dtype)
    imu = piece.imu
    if imu is not None and (len(inj.imu_glitch_idx) or inj.diverge_imu_idx is not None):
        acc, gyro = imu.acc.copy(), imu.gyro.copy()
        g0, g1 = np.searchsorted(inj.imu_glitch_idx, [imu_before, imu_before + len(imu)])
        acc[inj.imu_glitch_idx[g0:g1] - imu_before] = plan.glitch_acc[g0:g1]
        gyro[inj.imu_glitch_idx[g0:g1] - imu_before] = plan.glitch_gyro[g0:g1]
        k = inj.diverge_imu_idx
        if k is not None and imu_before <= k < imu_before + len(imu):
            acc[k - imu_before] = (1e30, -1e30, 1e30)         # finite, but no filter survives it
        imu = replace(imu, acc=acc, gyro=gyro)
    meta = dict(piece.meta)
    meta["faults"] = {"nlos": int(len(inj.nlos_idx)), "imu_glitches": int(len(inj.imu_glitch_idx)),
                      "outage_removed": inj.outage_removed, "diverge_t_us": inj.diverge_t_us}
    return replace(piece, uwb=replace(u, **sliced), imu=imu, meta=meta), int(len(value))


def inject_chunks(plan: SimPlan, faults: FlightFaults, chunk_s: float) -> tuple[Iterator[Flight], InjectedFaults]:
    """`inject` on a simulated flight built in slices: the slices of inject(plan.whole(), faults)."""
    imu_t = np.arange(plan.n_imu, dtype=np.int64) * (1_000_000 // IMU_RATE_HZ)
    fplan = plan_faults(faults, plan.name, plan.kind, plan.sched_t, imu_t)
    del imu_t

    def pieces() -> Iterator[Flight]:
        kept = imu = 0
        for piece in plan.chunks(chunk_s):
            n_imu = len(piece.imu) if piece.imu is not None else 0
            out, n_kept = apply_faults(piece, fplan, kept, imu)
            kept, imu = kept + n_kept, imu + n_imu
            yield out
    return pieces(), fplan.injected
