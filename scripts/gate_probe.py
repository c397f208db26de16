"""Why outlier rejection loses to no rejection on the UTIL obstacle flights, and what other gate designs do.

    python scripts/gate_probe.py log RECORDING... --anchors ANCHORS.csv
    python scripts/gate_probe.py variants RECORDING... --anchors ANCHORS.csv [--variants outlier,reopen,...]

Replays each recording through the numpy twin of the firmware (UWB-only, no network: the power-up gates
and configuration otherwise), the way `uwb-hil run --uwb-only --stages none|outlier` does.

`log` prints per flight what the gates without the lock-out guard (no-guard) reject and whether it was wrong (the true error of each measurement
from the recorded ground truth): per gate the count, the median |true error| of what it rejected and the
share of good links among them (|true error| < 0.15 m); the share of true outliers (|true error| > 0.3 m)
the gates let through; how much of the excess squared error over no rejection the three worst seconds
carry (capture episodes); an oracle bound: no rejection with every measurement of |true error| > 0.3 m
dropped; and no rejection with only the slowly varying error left (slow_only; both use the truth: bounds,
not methods). `--dump T0:T1` also prints every measurement of that stretch (status, true error,
innovation, z error, estimated vertical speed).

`variants` prints the position RMSE of gate designs (all keep the kinematic and chi-square tests and
change what follows from them):
  none, outlier        the presets (outlier: the firmware's gates, with the chi-square gate's lock-out guard
                       GATE_CHI2_REOPEN_US; `--reopen-ms` replays them with another guard time)
  no-guard             the gates without that guard (the paper's; the firmware before it)
and, on top of no-guard, twin-only probes that are not in the firmware:
  integrator           one gate state for the filter (the Crazyflie mainline TDoA filter's idea): a level
                       integrates +dt for a measurement that passes, -dt for one that fails (dt <= 30 ms,
                       level in [0, 0.3 s]); below 10 % of the window the gates open (accept all), above
                       90 % they close again
  rate-open            an exponential average (tau 0.3 s) of the share of measurements that fail; above
                       0.2 both gates open until it is below 0.1
  culprit              per anchor: two rejected links sharing an anchor (different partners) within 0.1 s
                       name that anchor the culprit; all its links are rejected for 0.3 s
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.biasnet.dataset import geometric_value
from harness.biasnet.recipes import load_recordings
from harness.config import PRESETS, EstimatorConfig
from harness.flight.data import KIND_TWR, Flight
from harness.flight.run_config import config_for
from harness.flight.scenarios import scenario_flight
from harness.twin import gates
from harness.twin.estimator import ACCEPTED, REJECTED_CHI2, REJECTED_KINEMATIC, TwinEstimator, TwinResult

GOOD = 0.15      # |true error| below this: a good link [m]
OUTLIER = 0.3    # |true error| above this: a true outlier [m]
SLOW = 0.25      # slow_only(): errors farther than this from their pair's median are not slow [m]


class NoGuard(TwinEstimator):
    """The gates without the chi-square gate's lock-out guard."""

    def _chi2_reopened(self) -> bool:
        return False


class Guard(TwinEstimator):
    """The firmware's gates with another guard time (--reopen-ms)."""

    REOPEN_US = gates.CHI2_REOPEN_US

    def _chi2_reopened(self) -> bool:
        return gates.chi2_reopened(self.kin.rejected_us, self.REOPEN_US)


class Integrator(NoGuard):
    """One level for the whole filter: sustained failures open the gates (module docstring)."""

    WINDOW_S, DT_CAP_S, OPEN, CLOSE = 0.3, 0.03, 0.1, 0.9

    def _gate_status(self, t_us: int, ids: tuple[int, int], y: float, d_max: float, S: float, tdoa: bool) -> int:
        status = super()._gate_status(t_us, ids, y, d_max, S, tdoa)
        last = getattr(self, "_t_last", None)
        dt = min((t_us - last) * 1e-6, self.DT_CAP_S) if last is not None else 0.0
        self._t_last = t_us
        level = getattr(self, "_level", self.WINDOW_S) + (dt if status == ACCEPTED else -dt)
        self._level = min(max(level, 0.0), self.WINDOW_S)
        is_open = getattr(self, "_open", False)
        is_open = self._level <= self.CLOSE * self.WINDOW_S if is_open else self._level < self.OPEN * self.WINDOW_S
        self._open = is_open
        return ACCEPTED if is_open else status


class RateOpen(NoGuard):
    """Both gates open while the recent failure rate is high (hysteresis HI / LO)."""

    TAU_S, HI, LO, DT_CAP_S = 0.3, 0.2, 0.1, 0.03

    def _gate_status(self, t_us: int, ids: tuple[int, int], y: float, d_max: float, S: float, tdoa: bool) -> int:
        status = super()._gate_status(t_us, ids, y, d_max, S, tdoa)
        last = getattr(self, "_t_last", None)
        a = min(min((t_us - last) * 1e-6, self.DT_CAP_S) / self.TAU_S, 1.0) if last is not None else 0.0
        self._t_last = t_us
        rate = getattr(self, "_rate", 0.0)
        self._rate = rate + a * (float(status != ACCEPTED) - rate)
        is_open = getattr(self, "_open", False)
        self._open = self._rate >= self.LO if is_open else self._rate > self.HI
        return ACCEPTED if self._open else status


class Culprit(NoGuard):
    """An anchor in two rejected links with different partners within T_S is held out for HOLD_S."""

    T_S, HOLD_S = 0.1, 0.3

    def _gate_status(self, t_us: int, ids: tuple[int, int], y: float, d_max: float, S: float, tdoa: bool) -> int:
        status = super()._gate_status(t_us, ids, y, d_max, S, tdoa)
        t = t_us * 1e-6
        if not hasattr(self, "_rej"):
            self._rej: dict[int, tuple[float, int]] = {}
            self._held: dict[int, float] = {}
        if status == ACCEPTED:
            return REJECTED_CHI2 if any(self._held.get(i, -1.0) > t for i in ids) else status
        for me, other in (ids, ids[::-1]):
            t_prev, partner = self._rej.get(me, (-1e9, -1))
            if t - t_prev < self.T_S and (partner != other or ids[0] == ids[1]):
                self._held[me] = t + self.HOLD_S
            self._rej[me] = (t, other)
        return status


VARIANTS: dict[str, type[TwinEstimator]] = {"none": TwinEstimator, "outlier": Guard, "no-guard": NoGuard,
                                            "integrator": Integrator, "rate-open": RateOpen, "culprit": Culprit}


def replay_results(flight: Flight, cfg: EstimatorConfig, cls: type[TwinEstimator] = TwinEstimator,
                   keep: np.ndarray | None = None, value: np.ndarray | None = None) -> list[TwinResult]:
    """The twin's results for the UWB measurements (those in ``keep``; values ``value`` if given)."""
    twin = cls(cfg, flight.anchors.as_dict())
    u = flight.uwb
    z = np.asarray(u.value, dtype=np.float64) if value is None else value
    out = []
    for t_us, source, i in flight.events():
        if source != 1 or (keep is not None and not keep[i]):
            continue
        if u.kind == KIND_TWR:
            out.append(twin.on_twr(t_us, int(u.anchor_a[i]), float(z[i])))
        else:
            out.append(twin.on_tdoa(t_us, int(u.anchor_a[i]), int(u.anchor_b[i]), float(z[i])))
    return out


def replay(flight: Flight, cfg: EstimatorConfig, cls: type[TwinEstimator] = TwinEstimator,
           keep: np.ndarray | None = None, value: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(positions (M, 3), statuses (M,)) of :func:`replay_results`."""
    res = replay_results(flight, cfg, cls, keep, value)
    return np.array([r.pos for r in res]), np.array([r.status for r in res])


def true_error(flight: Flight) -> np.ndarray:
    u = flight.uwb
    return np.asarray(u.value, dtype=np.float64) - geometric_value(flight, flight.truth.position_at(u.t_us))


def rmse(flight: Flight, pos: np.ndarray, keep: np.ndarray | None = None) -> float:
    t = flight.uwb.t_us if keep is None else flight.uwb.t_us[keep]
    return float(np.sqrt(np.mean(np.sum((pos - flight.truth.position_at(t)) ** 2, axis=1))))


def config(flight: Flight, name: str) -> EstimatorConfig:
    return config_for(flight, stages=PRESETS["none" if name == "none" else "outlier"], uwb_only=True)


def log(flight: Flight) -> None:
    err = np.abs(true_error(flight))
    p0, _ = replay(flight, config(flight, "none"))
    p1, st = replay(flight, config(flight, "outlier"), NoGuard)
    print(f"{flight.name}: {len(err)} measurements, RMSE none {rmse(flight, p0):.4f}, outlier {rmse(flight, p1):.4f} m")
    for code, name in ((REJECTED_KINEMATIC, "kinematic"), (REJECTED_CHI2, "chi-square")):
        m = st == code
        if m.any():
            print(f"  {name}: rejected {m.sum()} ({100 * m.mean():.1f} %), median |true error| {np.median(err[m]):.3f} m, "
                  f"good links among them {100 * np.mean(err[m] < GOOD):.0f} %")
    bad = err > OUTLIER
    print(f"  true outliers (|error| > {OUTLIER} m): {bad.sum()} ({100 * bad.mean():.1f} %), "
          f"accepted by the gates {100 * np.mean(st[bad] == ACCEPTED):.0f} %")
    sec = ((flight.uwb.t_us - flight.uwb.t_us[0]) // 1_000_000).astype(int)
    t = flight.uwb.t_us
    excess = np.bincount(sec, np.sum((p1 - flight.truth.position_at(t)) ** 2, axis=1)
                         - np.sum((p0 - flight.truth.position_at(t)) ** 2, axis=1))
    worst = np.argsort(-excess)[:3]
    print(f"  excess squared error over none: {excess.sum() / len(t):+.4f} m^2, of which the worst seconds "
          f"{', '.join(str(int(k)) for k in worst)}: {excess[worst].sum() / len(t):+.4f} m^2")
    keep = ~bad
    po, _ = replay(flight, config(flight, "none"), keep=keep)
    print(f"  oracle (none, true outliers dropped): {rmse(flight, po, keep):.4f} m")
    print(f"  slow error only (none, every error beyond {SLOW} m of its pair's median set to that median): "
          f"{rmse(flight, replay(flight, config(flight, 'none'), value=slow_only(flight))[0]):.4f} m")


def slow_only(flight: Flight) -> np.ndarray:
    """The measurements with every error farther than SLOW from its anchor pair's median error replaced by
    that median: what is left is the slowly varying error (truth used: a bound)."""
    u = flight.uwb
    err = true_error(flight)
    keys = np.asarray(u.anchor_a, dtype=np.int64) * 4096 + np.asarray(u.anchor_b, dtype=np.int64)
    med = np.zeros_like(err)
    for k in np.unique(keys):
        med[keys == k] = np.median(err[keys == k])
    out = np.asarray(u.value, dtype=np.float64)
    return np.where(np.abs(err - med) > SLOW, out - err + med, out)


def dump(flight: Flight, t0_s: float, t1_s: float) -> None:
    """Per measurement in [t0, t1) s after the first one, through the gates without the guard."""
    res = replay_results(flight, config(flight, "outlier"), NoGuard)
    u, err = flight.uwb, true_error(flight)
    t = (u.t_us - u.t_us[0]) * 1e-6
    truth = flight.truth.position_at(u.t_us)
    names = {ACCEPTED: "accepted", REJECTED_KINEMATIC: "kinematic", REJECTED_CHI2: "chi-square"}
    for i in np.flatnonzero((t >= t0_s) & (t < t1_s)):
        r = res[i]
        print(f"  {t[i]:8.3f} s  pair {u.anchor_a[i]}-{u.anchor_b[i]}  {names.get(r.status, '?'):10s} true error "
              f"{err[i]:+.2f}  innovation {r.innovation:+.2f}  z error {r.pos[2] - truth[i, 2]:+.2f}  vz {r.vel[2]:+.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("log", "variants"))
    ap.add_argument("recordings", type=Path, nargs="*")
    ap.add_argument("--sim-nlos", type=int, default=0, metavar="N",
                    help="also N seeds (1000...) of simulated obstacle-arena flights (error profile nlos, 40 s): "
                         "TDoA and TWR, circle and random")
    ap.add_argument("--dump", default=None, metavar="T0:T1",
                    help="log: also every measurement from T0 to T1 s after the first one")
    ap.add_argument("--reopen-ms", type=float, default=gates.CHI2_REOPEN_US / 1000, help="guard time of 'outlier'")
    ap.add_argument("--anchors", type=Path, default=None)
    ap.add_argument("--variants", default=",".join(VARIANTS), help="comma-separated, of: " + ", ".join(VARIANTS))
    args = ap.parse_args()
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variants {unknown}")
    Guard.REOPEN_US = int(round(args.reopen_ms * 1000))
    flights = load_recordings(args.recordings, args.anchors) if args.recordings else []
    flights += [scenario_flight(scen, mode=mode, duration_s=40.0, seed=1000 + k, profile="nlos")
                for mode in ("tdoa", "twr") for scen in ("circle", "random") for k in range(args.sim_nlos)]
    if not flights:
        ap.error("no flights: give recordings and/or --sim-nlos N")
    for flight in flights:
        if args.what == "log":
            log(flight)
            if args.dump:
                t0, _, t1 = args.dump.partition(":")
                dump(flight, float(t0), float(t1))
            continue
        cells = [f"{v} {rmse(flight, replay(flight, config(flight, v), VARIANTS[v])[0]):.4f}" for v in names]
        print(f"{flight.name}: " + ", ".join(cells), flush=True)


if __name__ == "__main__":
    main()
