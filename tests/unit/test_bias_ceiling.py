"""The floor (fast part of the error, per flight and anchor pair) and share_of_ceiling, on data whose answer
is known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from harness.biasnet.ceiling import HALF_WINDOW_S, fast_part, moving_average, share_of_ceiling
from harness.biasnet.dataset import Samples
from harness.biasnet.evaluate import evaluate

DT = 1.0 / 64.0  # exact in binary: a +-0.25 s window holds exactly 16 samples on each side


def fast_residual(samples: Samples, half_window_s: float = HALF_WINDOW_S) -> np.ndarray:
    """Each sample's error minus the moving average of its own (flight, anchor pair) series."""
    return fast_part(samples, half_window_s).residual


def floor_rmse(samples: Samples, half_window_s: float = HALF_WINDOW_S, unbiased: bool = False) -> float:
    """The literal floor (FastPart.floor) or with ``unbiased`` the small-window-corrected one; NaN for no
    samples."""
    if len(samples) == 0:
        return float("nan")
    part = fast_part(samples, half_window_s)
    return part.floor_unbiased() if unbiased else part.floor()


def make_samples(errors: list[tuple[int, int, int, np.ndarray]], dt: float | list[float] = DT) -> Samples:
    """(flight, anchor a, anchor b, error series sampled every dt from t = 0) -> Samples (dt: one for all
    series or one per series)."""
    parts = []
    dts = dt if isinstance(dt, list) else [dt] * len(errors)
    for (flight, a, b, e), step in zip(errors, dts):
        n = len(e)
        parts.append(Samples(layout=4, x=np.zeros((n, 6)), bias=np.asarray(e, float),
                             flight=np.full(n, flight), pair=np.tile([a, b], (n, 1)), names=("f",),
                             row=np.arange(n), t_s=np.arange(n) * step))
    s = Samples.concat(parts)
    # concat renumbers flights one per part; restore the intended flight ids
    return Samples(s.layout, s.x, s.bias, np.concatenate([np.full(len(e), f) for f, _, _, e in errors]),
                   s.pair, s.names, None, s.row, s.t_s)


def brute_moving_average(t: np.ndarray, e: np.ndarray, w: float) -> np.ndarray:
    return np.array([np.mean(e[np.abs(t - ti) <= w]) for ti in t])


def test_moving_average_equals_brute_force_on_irregular_times() -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.001, 0.05, 400))
    e = rng.standard_normal(400)
    np.testing.assert_allclose(moving_average(t, e, 0.25), brute_moving_average(t, e, 0.25), atol=1e-12)
    np.testing.assert_allclose(moving_average(t, e, 0.05), brute_moving_average(t, e, 0.05), atol=1e-12)


def test_constant_per_pair_and_flight_has_a_zero_floor_even_with_shared_times() -> None:
    # Same pair, same times, different constants in two flights: mixing them would leave a residual.
    n = 640
    s = make_samples([(0, 1, 2, np.full(n, 0.10)), (1, 1, 2, np.full(n, -0.20)), (0, 3, 4, np.full(n, 0.05))])
    assert np.max(np.abs(fast_residual(s))) < 1e-12
    assert floor_rmse(s) < 1e-12


def test_alternating_noise_on_constants_gives_the_known_floor_and_share() -> None:
    # error = c_pair + a * (-1)^k. A window of 33 samples (16 + 1 + 16) averages the alternation to
    # +-a/33, so inside the series the fast residual is +-a * 32/33 exactly; the 2 x 16 samples at each
    # series' ends see a truncated window and are excluded from the exact check.
    n, a = 6400, 0.05
    alt = a * (-1.0) ** np.arange(n)
    consts = (0.12, -0.08)
    s = make_samples([(0, 1, 2, consts[0] + alt), (0, 1, 3, consts[1] + alt)])
    r = fast_residual(s)
    inner = np.concatenate([np.arange(16, n - 16), n + np.arange(16, n - 16)])
    np.testing.assert_allclose(np.abs(r[inner]), a * 32.0 / 33.0, rtol=1e-9)
    assert floor_rmse(s) == pytest.approx(a * 32.0 / 33.0, rel=2e-3)
    # n = 33: the unbiased floor scales the squares by 33/32
    assert floor_rmse(s, unbiased=True) == pytest.approx(a * np.sqrt(32.0 / 33.0), rel=2e-3)
    # A correction that knows each pair's constant removes all the slow part: corrected RMSE = a.
    perfect = evaluate("perfect", s, lambda x: np.where(x.pair[:, 1] == 2, consts[0], consts[1]))
    raw = np.sqrt(np.mean(np.square(consts)) + a * a)
    assert perfect.overall.rmse_raw == pytest.approx(raw, rel=1e-9)
    assert perfect.overall.rmse_corrected == pytest.approx(a, rel=1e-9)
    expected = (raw - a) / (raw - a * 32.0 / 33.0)
    assert perfect.overall.share_of_ceiling == pytest.approx(expected, rel=5e-3)
    # Half of each constant: the cut in RMSE terms, measured against the same floor.
    half = evaluate("half", s, lambda x: 0.5 * np.where(x.pair[:, 1] == 2, consts[0], consts[1]))
    corr = np.sqrt(np.mean(np.square(consts)) / 4 + a * a)
    assert half.overall.share_of_ceiling == pytest.approx((raw - corr) / (raw - a * 32 / 33), rel=5e-3)
    assert half.per_pair["1-2"].rmse_floor == pytest.approx(a * 32 / 33, rel=5e-3)
    nothing = evaluate("none", s, lambda x: np.zeros(len(x)))
    assert nothing.overall.share_of_ceiling == pytest.approx(0.0, abs=1e-12)


def test_window_option_and_degenerate_cases() -> None:
    n = 640
    s = make_samples([(0, 1, 2, 0.05 * (-1.0) ** np.arange(n))])
    # +-0.5 s: 65 samples -> residual a * 64/65
    assert floor_rmse(s, 0.5) == pytest.approx(0.05 * 64 / 65, rel=5e-3)
    with pytest.raises(ValueError, match="half window"):
        fast_residual(s, 0.0)
    assert np.isnan(share_of_ceiling(0.05, 0.04, 0.06))  # nothing removable: undefined, not a number
    no_times = Samples(4, s.x, s.bias, s.flight, s.pair, s.names)
    with pytest.raises(ValueError, match="times"):
        floor_rmse(no_times)


@pytest.mark.parametrize("dt, n_window", [(0.25, 3), (0.125, 5), (1.0 / 6.0, 3), (0.1, 5)])
def test_white_noise_unbiased_floor_is_sigma_where_the_literal_one_is_sqrt_1_minus_1_over_n_low(
        dt: float, n_window: int) -> None:
    # White noise of std sigma sampled every dt: inside the series every +-0.25 s window holds n_window
    # samples, at each end fewer (n >= 2). The literal floor is sigma sqrt(1 - 1/n) (13-18 % low here), the
    # unbiased one sigma.
    sigma, n = 0.05, 60000
    rng = np.random.default_rng(11)
    s = make_samples([(0, 1, 2, sigma * rng.standard_normal(n)), (1, 1, 2, sigma * rng.standard_normal(n))], dt)
    part = fast_part(s)
    inner = part.n[n // 2]
    assert inner == n_window
    assert part.floor() == pytest.approx(sigma * np.sqrt(1.0 - 1.0 / n_window), rel=0.01)
    assert part.floor_unbiased() == pytest.approx(sigma, rel=0.01)
    assert floor_rmse(s, unbiased=True) == pytest.approx(sigma, rel=0.01)
    # The share of the ceiling against each: a correction removing nothing of white noise shares nothing.
    ev = evaluate("none", s, lambda x: np.zeros(len(x))).overall.as_dict()
    assert ev["floor_unbiased"] == pytest.approx(sigma, rel=0.01)
    assert ev["floor"] < ev["floor_unbiased"]


def test_windows_of_one_sample_are_left_out_of_the_unbiased_floor() -> None:
    # Pair 1-2 sampled every 1 s: each window holds only its own sample, residual 0, no information.
    # Pair 1-3 every 0.25 s (n = 3 inside). The literal floor counts pair 1-2 as zeros; the unbiased one is
    # pair 1-3's sigma; pair 1-2 alone has no unbiased floor (NaN), and no share against it.
    sigma, n = 0.04, 40000
    rng = np.random.default_rng(5)
    sparse = 0.1 + sigma * rng.standard_normal(n)
    dense = sigma * rng.standard_normal(n)
    s = make_samples([(0, 1, 2, sparse), (0, 1, 3, dense)], [1.0, 0.25])
    part = fast_part(s)
    assert np.all(part.n[:n] == 1) and np.max(np.abs(part.residual[:n])) < 1e-9  # 0 up to the cumsum's rounding
    assert part.floor_unbiased() == pytest.approx(sigma, rel=0.015)
    assert part.floor() == pytest.approx(sigma * np.sqrt(0.5 * 2.0 / 3.0), rel=0.015)
    ev = evaluate("none", s, lambda x: np.zeros(len(x)))
    assert np.isnan(ev.per_pair["1-2"].rmse_floor_unbiased)
    assert ev.per_pair["1-2"].rmse_floor < 1e-9
    assert np.isnan(ev.per_pair["1-2"].share_of_ceiling_unbiased)
    assert ev.per_pair["1-3"].rmse_floor_unbiased == pytest.approx(sigma, rel=0.015)


def test_share_against_the_unbiased_floor_is_larger_when_the_floor_rises() -> None:
    # Slow constant per pair + white noise on 3-sample windows: the slow part is removable; a perfect
    # correction leaves sigma, which is exactly the unbiased floor (share 1) and above the literal one
    # (share < 1).
    sigma, n, c = 0.05, 60000, 0.12
    rng = np.random.default_rng(2)
    s = make_samples([(0, 1, 2, c + sigma * rng.standard_normal(n))], 0.25)
    perfect = evaluate("perfect", s, lambda x: np.full(len(x), c)).overall
    assert perfect.share_of_ceiling_unbiased == pytest.approx(1.0, abs=0.02)
    raw, lit = perfect.rmse_raw, perfect.rmse_floor
    assert perfect.share_of_ceiling == pytest.approx((raw - perfect.rmse_corrected) / (raw - lit), rel=1e-12)
    assert perfect.share_of_ceiling < 0.93


def test_report_table_quotes_the_share_of_ceiling() -> None:
    from harness.report.bias_section import _heldout_rows
    methods = {"network": {"n": 10, "rmse_raw": 0.09, "reduction": 0.3, "share_of_ceiling": 0.814,
                           "share_of_ceiling_unbiased": 0.92},
               "pair-constant": {"reduction": 0.25}, "voxel-table": {"reduction": 0.31}}
    rows = _heldout_rows({"util_tdoa_pos": {"heldout": {"t5": methods}}})
    assert rows == [["util_tdoa_pos t5", "10", "0.0900", "30.0 %", "25.0 %", "31.0 %", "81 %", "-", "92 %", "-"]]
