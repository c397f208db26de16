"""Numerical health over a long simulated flight through the firmware: 20 % NLOS outliers, IMU glitches,
a 2 s UWB outage and one absurd IMU sample that forces a divergence.

Checked: every measurement answered, no NaN/Inf anywhere in the RESULTs, covariance diagonal positive and
bounded on the wire, and the FULL covariance (firmware_sim/fuzz/cov_health.c, same bytes, in-process)
finite, exactly symmetric, bounded and positive definite after every measurement; the divergence is
reported (ERROR DIVERGED) exactly once, and the filter re-converges after the outage and the divergence.
Also NEES over Monte-Carlo seeds (harness/report/consistency.py).

`make test` flies UWB_LONGFLIGHT_S = 150 s; `make longflight` flies 3600 s. The flight is built, faulted and
streamed in 30 s slices, so a 1-hour flight never sits in memory whole. Figures are printed (-s).
"""

from __future__ import annotations

import math

import os
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from harness.bench.memory import peak_rss_mb
from harness.config import PRESETS, EstimatorConfig
from harness.device.host import HostDevice
from harness.flight.chunked import SimPlan
from harness.flight.faults import FlightFaults, InjectedFaults, inject_chunks
from harness.flight.data import Flight
from harness.flight.scenarios import plan_scenario, scenario_flight
from harness.report.chi2 import chi2_cdf, chi2_quantile
from harness.report.consistency import monte_carlo_nees, position_nees
from harness.report.health import reconvergence_s, rejection_streaks
from harness.flight.run_config import config_for
from harness.paths import DEFAULT_FIRMWARE, REPO_ROOT
from harness.device.channel import setup_messages
from harness.stream.prepare import prepare
from harness.stream.chunked_run import stream_chunks
from harness.stream.streamer import OUTCOME_RESULT, RESULTS_DTYPE, Pacing, Streamer
from protocol import encode_frame
from protocol import messages as m

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason=f"{DEFAULT_FIRMWARE} not built (make firmware)")

DURATION_S = float(os.environ.get("UWB_LONGFLIGHT_S", "150"))
CHUNK_S = 30.0            # built and streamed in slices: bounded memory (harness/flight/chunked.py)
CONVERGED_M = 0.35        # "re-converged": error below this for 1 s
FW = REPO_ROOT / "firmware_sim"


@dataclass
class LongRun:
    gates: str
    flight: Flight           # compact: the (faulted) measurements and the truth at their times, no IMU
    n_imu: int
    cfg: EstimatorConfig
    results: np.ndarray
    errors: list[m.Error]
    injected: InjectedFaults
    err: np.ndarray          # position error per measurement [m]
    wall_s: float
    peak_rss_mb: float


#: chi2: the chi-square gate alone; outlier: kinematic + chi-square gates (the paper's configuration)
GATES = {"chi2": int(m.Stage.CHI2_GATE), "outlier": PRESETS["outlier"]}


def _faults(duration: float) -> FlightFaults:
    return FlightFaults(nlos_fraction=0.2, imu_glitch_rate=1e-3, outage_start_s=0.4 * duration, outage_len_s=2.0,
                        diverge_at_s=0.7 * duration, seed=17)


@dataclass
class LongFlight:
    """The faulted flight, never whole in memory: built and faulted slice by slice, as often as needed."""

    plan: SimPlan
    injected: InjectedFaults

    def chunks(self) -> Iterator[Flight]:
        return inject_chunks(self.plan, _faults(DURATION_S), CHUNK_S)[0]


@pytest.fixture(scope="module")
def long_flight() -> LongFlight:
    plan = plan_scenario("random", mode="twr", duration_s=DURATION_S, seed=31, noise="gaussian", noise_std=0.1)
    return LongFlight(plan, inject_chunks(plan, _faults(DURATION_S), CHUNK_S)[1])


@pytest.fixture(scope="module", params=list(GATES))
def long_run(request: pytest.FixtureRequest, long_flight: LongFlight,
             tmp_path_factory: pytest.TempPathFactory) -> LongRun:
    log_dir = tmp_path_factory.mktemp("longflight")
    t0 = time.perf_counter()
    with HostDevice(DEFAULT_FIRMWARE, log_dir=log_dir) as dev:
        dev.hello(timeout=10.0)
        streamer = Streamer(dev, timeout_s=10.0)
        out = stream_chunks(streamer, long_flight.chunks(),
                            lambda first: config_for(first, EstimatorConfig(), stages=GATES[request.param]),
                            Pacing("windowed", 64))
    wall = time.perf_counter() - t0
    flight, results = out.flight, out.run.results
    truth = flight.truth.position_at(flight.uwb.t_us.astype(np.int64))
    est = np.stack([results["px"], results["py"], results["pz"]], axis=1).astype(np.float64)
    return LongRun(request.param, flight, long_flight.plan.n_imu, out.run.config, results, out.run.errors,
                   long_flight.injected, np.linalg.norm(est - truth, axis=1), wall,
                   peak_rss_mb())


def test_every_measurement_answered_and_finite(long_run: LongRun) -> None:
    res = long_run.results
    assert len(res) == len(long_run.flight.uwb)
    assert np.all(res["outcome"] == OUTCOME_RESULT)
    for name, _ in m.Result.FIELDS:
        col = res[name]
        if col.dtype.kind == "f":
            assert np.all(np.isfinite(col)), name
    for v in ("var_x", "var_y", "var_z", "var_vx", "var_vy", "var_vz", "var_d0", "var_d1", "var_d2"):
        assert np.all(res[v] >= 1e-6) and np.all(res[v] <= 100.0), v


def test_divergence_is_detected_and_reported_once(long_run: LongRun) -> None:
    diverged = [e for e in long_run.errors if e.code == m.ErrorCode.DIVERGED]
    assert [e for e in long_run.errors if e.code != m.ErrorCode.DIVERGED] == []
    # every guard firing is reported, numbered 1, 2, ... (detail = divergences since power-up)
    assert len(diverged) >= 1 and [e.detail for e in diverged] == list(range(1, len(diverged) + 1))
    assert all(e.msg_type == m.Imu.MSG_ID for e in diverged)
    assert len(diverged) == 1, diverged


def _figures(run: LongRun) -> dict[str, float]:
    inj = run.injected
    t = run.flight.uwb.t_us
    a, b = inj.outage_us
    quiet = np.ones(len(t), bool)
    for start in (b, inj.diverge_t_us):
        quiet &= ~((t >= start - 3_000_000) & (t < start + 10_000_000))
    status = run.results["status"]
    streaks = rejection_streaks(run.results, 1.0)
    return {"rmse_quiet": float(np.sqrt(np.mean(run.err[quiet] ** 2))),
            "err_p95_before_outage": float(np.percentile(run.err[(t >= a - 10_000_000) & (t < a)], 95)),
            "err_at_outage_end": float(run.err[np.searchsorted(t, b)]),
            "reconverge_outage_s": reconvergence_s(t, run.err, b, CONVERGED_M),
            "reconverge_divergence_s": reconvergence_s(t, run.err, inj.diverge_t_us, CONVERGED_M),
            "accepted": float(np.mean(status == 0)), "rejected_kinematic": float(np.mean(status == 1)),
            "rejected_chi2": float(np.mean(status == 2)), "lockouts": float(len(streaks)),
            "longest_lockout_s": max((s.duration_s for s in streaks), default=0.0)}


def test_reconverges_after_outage_and_divergence(long_run: LongRun) -> None:
    inj = long_run.injected
    t = long_run.flight.uwb.t_us
    a, b = inj.outage_us
    assert not np.any((t >= a) & (t < b)) and inj.outage_removed > 0       # the outage happened
    f = _figures(long_run)
    print(f"\nlong flight {DURATION_S:.0f} s, gates {long_run.gates}: {len(t)} UWB, {long_run.n_imu} IMU, "
          f"{len(inj.nlos_idx)} NLOS outliers, {len(inj.imu_glitch_idx)} IMU glitches, outage removed "
          f"{inj.outage_removed}; wall {long_run.wall_s:.1f} s ({DURATION_S / long_run.wall_s:.0f}x real time), "
          f"peak RSS of this process {long_run.peak_rss_mb:.0f} MB\n  "
          + ", ".join(f"{k} {v:.3f}" for k, v in f.items()))
    assert f["lockouts"] == 0
    assert f["rmse_quiet"] < 0.3
    assert f["reconverge_outage_s"] < 2.0
    assert f["reconverge_divergence_s"] < 2.0


@pytest.fixture(scope="module")
def cov_health_exe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    exe = tmp_path_factory.mktemp("covh") / "cov_health"
    srcs = sorted(str(p.relative_to(FW)) for d in ("core", "proto", "app") for p in (FW / d).glob("*.c"))
    cmd = ["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-Icore", "-Iproto", "-Iapp", "-Imodels", "-O1", "-g",
           "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-D_POSIX_C_SOURCE=200809L", "-o", str(exe),
           "fuzz/cov_health.c", *srcs, "host/platform_host.c", "-lm"]
    subprocess.run(cmd, cwd=FW, check=True, timeout=300)
    return exe


def test_full_covariance_stays_symmetric_positive_definite(long_run: LongRun, long_flight: LongFlight,
                                                           cov_health_exe: Path) -> None:
    flight = long_run.flight
    proc = subprocess.Popen([str(cov_health_exe)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert proc.stdin is not None
    seq = 0
    for i, piece in enumerate(long_flight.chunks()):
        msgs = setup_messages(long_run.cfg, piece.anchors, reset=(i == 0))
        setup = b"".join(encode_frame(msg, seq + k) for k, msg in enumerate(msgs))
        prep = prepare(piece, seq + len(msgs))
        seq = prep.next_seq
        proc.stdin.write(setup + prep.stream)
    proc.stdin.write(encode_frame(m.StatsReq(), seq))
    out, _ = proc.communicate(timeout=1800)
    assert proc.returncode == 0
    words = out.decode().split()
    figures = {k: float(v) for k, v in zip(words[0::2], words[1::2])}
    print(f"\nfull covariance after every RESULT, gates {long_run.gates}: {figures}")
    assert figures["results"] == len(flight.uwb) == figures["checks"]
    assert figures["non_finite"] == figures["out_of_bounds"] == 0 and figures["asym_max"] == 0.0
    assert figures["max_abs"] <= 100.0 and figures["diverged_errors"] >= 1
    assert figures["not_pd"] == 0 and figures["min_pivot"] > 0 and figures["diverged_errors"] == 1


# --------------------------------------------------------------------------------------------- NEES
# scipy.stats.chi2.ppf(p, k) (SciPy 1.x), to the digits printed in statistical tables and beyond
CHI2_TABLE = [(0.975, 1, 5.023886187314888), (0.025, 1, 0.0009820691171752555), (0.025, 3, 0.21579528262389785),
              (0.975, 3, 9.348403604496148), (0.025, 6, 1.2373442457912027), (0.975, 6, 14.44937533544792),
              (0.025, 30, 16.79077226556663), (0.975, 30, 46.97924224367115), (0.025, 300, 253.91232260248975),
              (0.975, 300, 349.87446882991526), (0.025, 3000, 2850.084936519793)]


@pytest.mark.parametrize("p,k,expected", CHI2_TABLE)
def test_chi2_quantile_is_exact(p: float, k: int, expected: float) -> None:
    assert chi2_quantile(p, k) == pytest.approx(expected, rel=1e-9)
    assert chi2_cdf(chi2_quantile(p, k), k) == pytest.approx(p, abs=1e-12)


def test_chi2_with_two_degrees_of_freedom_has_its_closed_form() -> None:
    # k = 2 is the exponential distribution: cdf = 1 - exp(-x/2), quantile = -2 ln(1 - p)
    for p in (1e-6, 0.025, 0.5, 0.95, 0.999999):
        assert chi2_quantile(p, 2) == pytest.approx(-2.0 * math.log1p(-p), rel=1e-10)
    with pytest.raises(ValueError):
        chi2_quantile(1.0, 3)


def test_nees_of_a_consistent_synthetic_estimator_is_three() -> None:
    rng = np.random.default_rng(5)
    runs = []
    for _ in range(20):
        res = np.zeros(500, RESULTS_DTYPE)
        truth = rng.normal(size=(500, 3))
        sd = rng.uniform(0.05, 0.5, (500, 3))
        est = truth + sd * rng.normal(size=(500, 3))
        for j, (p, v) in enumerate((("px", "var_x"), ("py", "var_y"), ("pz", "var_z"))):
            res[p], res[v] = est[:, j], sd[:, j] ** 2
        res["outcome"] = OUTCOME_RESULT
        runs.append(position_nees(res, truth))
    s = monte_carlo_nees(runs)
    assert s.anees == pytest.approx(3.0, abs=0.1)
    assert 0.9 < s.inside <= 1.0
    over = monte_carlo_nees([r * 4 for r in runs])          # variances 4x too small
    assert over.anees == pytest.approx(12.0, abs=0.4) and over.above > 0.9


def test_nees_over_monte_carlo_seeds_on_the_firmware(tmp_path: Path) -> None:
    """8 seeds of the same 10 s flight (Gaussian noise, no outliers) through the firmware."""
    nees = []
    with HostDevice(DEFAULT_FIRMWARE, log_dir=tmp_path) as dev:
        dev.hello(timeout=10.0)
        streamer = Streamer(dev)
        for seed in range(8):
            flight = scenario_flight("circle", mode="twr", duration_s=10.0, seed=100 + seed, noise="gaussian",
                                     noise_std=0.1)
            cfg = config_for(flight, EstimatorConfig(), stages=PRESETS["outlier"])
            run = streamer.run(flight, cfg, Pacing("windowed", 64))
            truth = flight.truth.position_at(flight.uwb.t_us.astype(np.int64))
            nees.append(position_nees(run.results, truth))
    s = monte_carlo_nees(nees, skip=400)          # skip the first 2 s (convergence from the initial guess)
    print(f"\nNEES over 8 seeds (circle, TWR, 0.1 m Gaussian): {s.as_dict()}")
    assert s.runs == 8 and s.epochs > 1000
    assert np.isfinite(s.anees) and s.anees > 0
    assert 0.0 <= s.inside <= 1.0 and s.lo < 3.0 < s.hi
