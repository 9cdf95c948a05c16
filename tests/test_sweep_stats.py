"""Replicas combined (their coverage on synthetic data of known variance), crossings, fits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flocking.analysis import PolarOrder
from flocking.sweep.stats import combine, crossings, exponent, peak

scipy = pytest.importorskip("scipy")
from scipy import integrate, stats  # noqa: E402


def expected_coverage(replicas: int, floor: float = 1.0) -> float:
    """P(|m - mu| <= error) for Gaussian replicas of equal variance whose within-run
    errors explain a fraction ``floor`` of it: the error is ``sqrt(max(floor, Q))`` in
    units of the true error, ``Q ~ chi^2_{R-1} / (R - 1)``, independent of ``m``."""
    k = replicas - 1
    density = lambda q: stats.chi2.pdf(q * k, k) * k  # noqa: E731
    value, _ = integrate.quad(lambda q: math.erf(math.sqrt(max(floor, q) / 2)) * density(q), 0, np.inf, limit=200)
    return value


def coverage(mean, error, mu) -> tuple[float, float]:
    """Fraction of intervals ``mean +- error`` holding ``mu``, and its binomial error."""
    hit = np.abs(mean - mu) <= error
    p = hit.mean()
    return p, math.sqrt(p * (1 - p) / hit.size)


def test_the_combination_keeps_each_replicas_error_and_the_scatter():
    # one replica: its own error; agreeing replicas: the within-run error, never 0
    assert combine([0.3], [0.02]) == (pytest.approx(0.3), pytest.approx(0.02))
    mean, error = combine([0.5, 0.5, 0.5], [0.03, 0.04, 0.12])
    assert mean == pytest.approx(0.5) and error == pytest.approx(math.sqrt(0.03**2 + 0.04**2 + 0.12**2) / 3)
    # scatter beyond the errors: the standard error
    values = np.array([0.1, 0.5, 0.9])
    mean, error = combine(values, [0.001] * 3)
    assert error == pytest.approx(values.std(ddof=1) / math.sqrt(3))
    # failed runs are left out; no value at all: NaN
    mean, error = combine([[0.4, np.nan, 0.6], [np.nan, np.nan, np.nan]], [[0.01, 0.01, 0.01]] * 2)
    assert mean[0] == pytest.approx(0.5) and error[0] == pytest.approx(0.1)
    assert np.isnan(mean[1]) and np.isnan(error[1])
    # unknown within-run errors (an older results file): the standard error alone
    mean, error = combine([0.4, 0.6], [np.nan, np.nan])
    assert error == pytest.approx(0.1)
    assert np.isnan(combine([0.4], [np.nan])[1])
    # along another axis
    mean, error = combine(np.array([[0.4, 0.5], [0.6, 0.5]]), 0.0, axis=0)
    assert mean.tolist() == pytest.approx([0.5, 0.5]) and error.tolist() == pytest.approx([0.1, 0.0])


@pytest.mark.parametrize("replicas", [2, 3, 5])
def test_coverage_with_exact_errors_is_what_the_derivation_says(replicas):
    rng = np.random.default_rng(replicas)
    trials, sigma, mu = 40_000, 0.05, 0.4
    x = mu + sigma * rng.standard_normal((trials, replicas))
    mean, error = combine(x, np.full_like(x, sigma))
    p, dp = coverage(mean, error, mu)
    assert abs(p - expected_coverage(replicas)) < 4 * dp
    # the standard error alone falls short of one sigma: Student's t with R - 1 degrees of freedom
    sem = x.std(axis=1, ddof=1) / math.sqrt(replicas)
    p_sem, dp_sem = coverage(mean, sem, mu)
    assert abs(p_sem - (2 * stats.t.cdf(1, replicas - 1) - 1)) < 4 * dp_sem


def test_coverage_with_unequal_errors_never_falls_below_one_sigma():
    """Each replica with its own variance (known to it): the error is at least the true
    standard deviation of the mean, so the coverage is at least 68.3%."""
    rng = np.random.default_rng(7)
    trials, mu = 40_000, 1.0
    sigma = np.array([0.01, 0.03, 0.1])
    x = mu + sigma * rng.standard_normal((trials, 3))
    mean, error = combine(x, np.broadcast_to(sigma, x.shape))
    assert (error >= math.sqrt((sigma**2).sum()) / 3 * (1 - 1e-12)).all()
    p, dp = coverage(mean, error, mu)
    assert p >= 0.6827 - 4 * dp


def test_runs_stuck_in_different_states_are_caught_by_the_scatter():
    """Each run sits in a state of its own (an offset 10x its within-run error, as near a
    discontinuous transition): the within-run errors alone would cover ~8%; the
    combination falls back on the scatter and covers what the derivation says."""
    rng = np.random.default_rng(11)
    trials, replicas, sigma, spread = 40_000, 3, 0.01, 0.1
    x = 0.5 + spread * rng.standard_normal((trials, replicas)) + sigma * rng.standard_normal((trials, replicas))
    mean, error = combine(x, np.full_like(x, sigma))
    total = math.sqrt(spread**2 + sigma**2)
    p, dp = coverage(mean, error, 0.5)
    assert abs(p - expected_coverage(replicas, floor=(sigma / total) ** 2)) < 4 * dp
    p_within, _ = coverage(mean, np.full(trials, sigma / math.sqrt(replicas)), 0.5)
    assert p_within < 0.15


@pytest.mark.filterwarnings("ignore:PolarOrder. the window does not look equilibrated:RuntimeWarning")
def test_coverage_of_time_series_through_polar_order():
    """End to end: replicas are correlated series (AR(1), rho = 0.8, integrated time 4.5)
    of known mean; each gets its error from PolarOrder's autocorrelation time. The
    estimated errors scatter (Sokal's window: a relative error of ~sqrt(11 tau / T) = 16%
    on the variance), so the coverage is that of exact errors within a few percent: at
    least 68.3% - 3% - 4 binomial errors, and at most 73.1% + 3% + 4."""
    rng = np.random.default_rng(5)
    trials, replicas, length, rho, mu = 600, 3, 2000, 0.8, 0.6
    noise = rng.standard_normal((trials, replicas, length)) * 0.01
    x = np.empty_like(noise)
    x[..., 0] = noise[..., 0] / math.sqrt(1 - rho**2)
    for t in range(1, length):
        x[..., t] = rho * x[..., t - 1] + noise[..., t]
    x += mu
    means = x.mean(axis=2)
    errors = np.array([[PolarOrder().compute(x[i, r]).mean_error for r in range(replicas)] for i in range(trials)])
    mean, error = combine(means, errors)
    p, dp = coverage(mean, error, mu)
    print(f"coverage {p:.3f} +- {dp:.3f}")
    assert 0.6827 - 0.03 - 4 * dp <= p <= expected_coverage(replicas) + 0.03 + 4 * dp


def test_peaks_crossings_and_exponents():
    assert peak([1, 2, 3], [np.nan, 0.2, 0.1], [0.0, 0.01, 0.01]) == (2.0, 0.2, 0.01)
    assert all(math.isnan(v) for v in peak([1, 2], [np.nan, np.nan], [0, 0]))
    x = np.linspace(0, 5, 11)
    g_small, g_large = 0.6 - 0.05 * x, 0.7 - 0.1 * x  # cross at x = 2
    assert crossings(x, g_small, g_large) == [pytest.approx(2.0)]
    assert crossings(x, g_small, g_small + 0.1) == []
    # chi_max = 0.3 N^0.875 with 5% errors: the slope and an error that covers it
    n = np.array([256, 1024, 4096, 16384])
    rng = np.random.default_rng(2)
    chi = 0.3 * n**0.875 * (1 + 0.05 * rng.standard_normal(len(n)))
    slope, intercept, error = exponent(n, chi, 0.05 * chi)
    assert abs(slope - 0.875) < 4 * error and 0.005 < error < 0.1
    assert all(math.isnan(v) for v in exponent([100], [1.0], [0.1]))
