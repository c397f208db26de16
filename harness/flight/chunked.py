"""Simulated flights built in time slices, so a 1-hour flight never sits in memory whole.

`SimPlan` (made by `harness.flight.scenarios.plan_scenario`) holds what a simulated flight needs besides
its arrays: the trajectory, the measurement schedule (compact: times and anchor ids), and the random
generators' starting states. `plan.whole()` builds the flight in one piece (what `scenario_flight`
returns); `plan.chunks(chunk_s)` yields consecutive slices (`Flight`s) that, put together, are exactly
that flight: same truth, IMU samples and measurements, bit for bit (tests/device/test_streaming.py).

How the randomness stays the same: the whole flight draws from one generator per purpose in a fixed
order of bulk draws (segments, e.g. "a.multipath" then "a.delayed" ... then "noise"). numpy's
generators give the same numbers whether a segment is drawn at once or in consecutive pieces, so the
slices use one generator per segment, each started where the whole flight's generator would start that
segment (found once by drawing and discarding the preceding segments: `SegmentedRng`).

Slices are cut at 1 kHz IMU samples: slice [k0, k1) carries IMU samples k0..k1-1, the measurements with
k0 <= t < k1 (in ms), and truth samples k0..k1 (one more, so attitude and position interpolate to the
slice's last measurement as in the whole flight; consecutive slices share that sample).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterator

import numpy as np

from harness.flight.arena import Arena
from harness.flight.measurement_errors import (IMU_DRAW_LAYOUT, ImuCarry, RngSource, SimConfig, imu_errors_continued,
                                         quantise, uwb_draw_layout, uwb_errors)
from harness.flight.data import KIND_TWR, Flight, ImuStream, Truth, UwbStream
from harness.flight.trajectory import SampleCarry, Trajectory, sample_continued

IMU_RATE_HZ = 1000
_US_PER_IMU = 1_000_000 // IMU_RATE_HZ
_SKIP_BLOCK = 1 << 18


class SegmentedRng:
    """One generator per named segment of a generator's bulk-draw sequence (module doc)."""

    def __init__(self, gen: np.random.Generator, layout: list[tuple[str, str, int]]) -> None:
        scout = _copy(gen)
        self._gens: dict[str, np.random.Generator] = {}
        for name, method, count in layout:
            self._gens[name] = _copy(scout)
            draw = {"random": scout.random, "normal": scout.standard_normal,
                    "exponential": scout.standard_exponential}[method]
            left = count
            while left > 0:           # the parameters (scale, loc) do not change how many bits a draw takes
                k = min(left, _SKIP_BLOCK)
                draw(k)
                left -= k

    def __call__(self, segment: str) -> np.random.Generator:
        return self._gens[segment]


def _copy(gen: np.random.Generator) -> np.random.Generator:
    bit = type(gen.bit_generator)()
    bit.state = gen.bit_generator.state
    return np.random.Generator(bit)


@dataclass
class SimPlan:
    """A simulated flight before its arrays are built (made by scenarios.plan_scenario)."""

    name: str
    arena: Arena
    traj: Trajectory
    cfg: SimConfig
    kind: int
    noise: str
    noise_std: float
    sched_t: np.ndarray          # (M,) measurement times [us]
    sched_a: np.ndarray          # (M,) anchor ids
    sched_b: np.ndarray          # (M,) second anchor (TDoA) or -1
    rng_uwb: np.random.Generator
    rng_imu: np.random.Generator
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def n_imu(self) -> int:
        return int(np.floor(self.traj.duration * IMU_RATE_HZ)) + 1

    @property
    def n_uwb(self) -> int:
        return int(self.sched_t.shape[0])

    def whole(self) -> Flight:
        """The flight in one piece (draws straight from the generators, in the original order)."""
        flight, _, _ = self._slice(0, self.n_imu, _copy(self.rng_uwb), _copy(self.rng_imu), None, None)
        flight.validate()
        return flight

    def bounds(self, chunk_s: float) -> list[tuple[int, int]]:
        """IMU-sample bounds [k0, k1) of the slices; no slice is left without a measurement."""
        if not chunk_s > 0:
            raise ValueError(f"chunk_s must be > 0, got {chunk_s}")
        step = max(1, int(round(chunk_s * IMU_RATE_HZ)))
        n_imu, out, k0 = self.n_imu, [], 0
        while k0 < n_imu:
            k1 = min(n_imu, k0 + step)
            if k1 < n_imu and int(np.searchsorted(self.sched_t, k1 * _US_PER_IMU)) >= self.n_uwb:
                k1 = n_imu          # only trailing IMU samples would be left: they go into this slice
            out.append((k0, k1))
            k0 = k1
        return out

    def chunks(self, chunk_s: float = 30.0) -> Iterator[Flight]:
        """Consecutive slices of about `chunk_s` seconds; together exactly `whole()`."""
        n = self.n_uwb
        src_uwb = SegmentedRng(self.rng_uwb, _uwb_layout(self.noise, self.kind, n))
        src_imu = SegmentedRng(self.rng_imu, _imu_layout(self.noise, self.n_imu))
        carry: SampleCarry | None = None
        imu_carry: ImuCarry | None = None
        for k0, k1 in self.bounds(chunk_s):
            piece, carry, imu_carry = self._slice(k0, k1, src_uwb, src_imu, carry, imu_carry)
            yield piece

    def _slice(self, k0: int, k1: int, rng_uwb: RngSource, rng_imu: RngSource, carry: SampleCarry | None,
               imu_carry: ImuCarry | None) -> tuple[Flight, SampleCarry, ImuCarry | None]:
        n_imu = self.n_imu
        k_end = min(k1 + 1, n_imu)                     # truth: one sample past the slice (module doc)
        t_truth = np.arange(k0, k_end, dtype=np.int64) * _US_PER_IMU
        s, next_carry = sample_continued(self.traj, t_truth * 1e-6, carry, carry_at=k1 - 1 - k0)
        truth = Truth(t_us=t_truth, pos=s.pos, quat=s.quat, vel=s.vel)
        m = k1 - k0
        i0 = int(np.searchsorted(self.sched_t, k0 * _US_PER_IMU))
        i1 = self.n_uwb if k1 >= n_imu else int(np.searchsorted(self.sched_t, k1 * _US_PER_IMU))
        t_us, a_ids, b_ids = self.sched_t[i0:i1], self.sched_a[i0:i1], self.sched_b[i0:i1]
        m_pos = self.traj.pos(t_us * 1e-6)
        true_value = _true_values(self.arena, self.kind, m_pos, a_ids, b_ids)
        f_body, omega = s.f_body[:m], s.omega[:m]
        if self.noise == "none":
            value = true_value.copy()
            acc, gyro = f_body.copy(), omega.copy()
        else:
            if self.noise == "gaussian":
                value = true_value + _gen(rng_uwb, "noise").normal(0.0, self.noise_std, size=true_value.shape)
            else:
                err = uwb_errors(self.cfg, self.kind, self.arena, m_pos, truth.quat_at(t_us), a_ids, b_ids, rng_uwb)
                value = quantise(true_value + err.total, self.cfg.quantum_m)
            acc, gyro, imu_carry = imu_errors_continued(f_body, omega, 1.0 / IMU_RATE_HZ, self.cfg.imu, rng_imu,
                                                        imu_carry)
        flight = Flight(name=self.name, anchors=self.arena.anchors,
                        uwb=UwbStream(kind=self.kind, t_us=t_us, anchor_a=a_ids, anchor_b=b_ids, value=value,
                                      true_value=true_value),
                        truth=truth, imu=ImuStream(t_us=t_truth[:m], acc=acc, gyro=gyro), meta=dict(self.meta))
        return flight, next_carry, imu_carry


def _gen(rng: RngSource, segment: str) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else rng(segment)


def _uwb_layout(noise: str, kind: int, n: int) -> list[tuple[str, str, int]]:
    if noise == "none":
        return []
    if noise == "gaussian":
        return [("noise", "normal", n)]
    return [(name, method, per * n) for name, method, per in uwb_draw_layout(kind)]


def _imu_layout(noise: str, n_imu: int) -> list[tuple[str, str, int]]:
    if noise == "none":
        return []
    return [(name, method, per * n_imu if per else 3) for name, method, per in IMU_DRAW_LAYOUT]


def _true_values(arena: Arena, kind: int, m_pos: np.ndarray, a_ids: np.ndarray, b_ids: np.ndarray) -> np.ndarray:
    index = {int(i): k for k, i in enumerate(arena.anchors.ids)}
    pa = arena.anchors.positions[np.array([index[int(i)] for i in a_ids], dtype=np.int64)].reshape(-1, 3)
    da = np.linalg.norm(m_pos - pa, axis=1)
    if kind == KIND_TWR:
        return da
    pb = arena.anchors.positions[np.array([index[int(i)] for i in b_ids], dtype=np.int64)].reshape(-1, 3)
    return np.linalg.norm(m_pos - pb, axis=1) - da


def concat_flights(pieces: list[Flight]) -> Flight:
    """Slices from `SimPlan.chunks` put back together (the shared truth sample is kept once)."""
    first = pieces[0]
    u = [p.uwb for p in pieces]
    truth_t, truth_pos, truth_q, truth_v = [], [], [], []
    for i, p in enumerate(pieces):
        keep = slice(0, len(p.truth.t_us) - 1) if i + 1 < len(pieces) else slice(None)
        truth_t.append(p.truth.t_us[keep])
        truth_pos.append(p.truth.pos[keep])
        truth_q.append(p.truth.quat[keep] if p.truth.quat is not None else np.zeros((0, 4)))
        truth_v.append(p.truth.vel[keep] if p.truth.vel is not None else np.zeros((0, 3)))
    imus = [p.imu for p in pieces if p.imu is not None]
    cat: Any = np.concatenate
    uwb = UwbStream(kind=first.uwb.kind, t_us=cat([x.t_us for x in u]), anchor_a=cat([x.anchor_a for x in u]),
                    anchor_b=cat([x.anchor_b for x in u]), value=cat([x.value for x in u]),
                    true_value=cat([x.true_value for x in u]) if all(x.true_value is not None for x in u) else None)
    truth = Truth(t_us=cat(truth_t), pos=cat(truth_pos), quat=cat(truth_q) if first.truth.quat is not None else None,
                  vel=cat(truth_v) if first.truth.vel is not None else None)
    imu = ImuStream(t_us=cat([x.t_us for x in imus]), acc=cat([x.acc for x in imus]),
                    gyro=cat([x.gyro for x in imus])) if imus else None
    return replace(first, uwb=uwb, truth=truth, imu=imu, meta=dict(first.meta))


__all__ = ["SegmentedRng", "SimPlan", "concat_flights", "IMU_RATE_HZ"]
