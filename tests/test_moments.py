"""The moments of the polar order over a window, and their error bars, against known answers.

The Binder cumulant ``G = 1 - <phi^4> / (3 <phi^2>^2)`` and the susceptibility
``chi = N (<phi^2> - <phi>^2)`` of constructed series whose moments are exact, through
every public way to get them: :func:`flocking.observables.polar_moments`,
:class:`flocking.analysis.PolarOrder` and a sweep's record
(:func:`flocking.sweep.point.summarise`). The error bars (a block jackknife) of series
whose statistics are known in closed form, derived here by the delta method:

- a Bernoulli series (``phi = 1`` with probability ``p``, else 0) has ``phi^2 = phi^4 = phi``,
  so ``G = 1 - 1 / (3 p)`` and ``Var G = p (1 - p) / (9 p^4 T)``;
- a zero-mean Gaussian series of variance ``s^2`` has ``G = 0``. To first order
  ``dG = g2 dm2 + g4 dm4`` with ``g2 = 2 / s^2`` and ``g4 = -1 / (3 s^4)``, so ``G`` moves
  with the mean of ``f(x) = 2 y - y^2 / 3``, ``y = x^2 / s^2``. For two values of a Gaussian
  process with correlation ``r`` (Isserlis' theorem), ``Cov(y, y') = 2 r^2``,
  ``Cov(y, y'^2) = 12 r^2`` and ``Cov(y^2, y'^2) = 72 r^2 + 24 r^4``, so
  ``Cov(f, f') = 8 r^2 + (72 r^2 + 24 r^4) / 9 - 16 r^2 = (8/3) r^4``. Independent values:
  ``Var G = 8 / (3 T)``. An AR(1) process (``r = rho^k`` at lag ``k``):
  ``Var G = 8 / (3 T) (1 + rho^4) / (1 - rho^4)``; likewise ``Var chi = 2 N^2 s^4 / T
  (1 + rho^2) / (1 - rho^2)`` and ``Var <phi> = s^2 / T (1 + rho) / (1 - rho)``.

Tolerances. A jackknife over ``B`` blocks estimates a standard error with a relative scatter
of about ``1 / sqrt(2 B)``: below 0.5 % for the independent series here (``T = 200000``,
blocks of 2 or 3 values), so 5 % is a wide bound that still refuses an error bar off by any
factor above 1.05. Blocks of ``b`` values from a correlated series also miss the
correlations that reach across block edges, which lowers the variance by
``2 sum_k k c_k / (b (1 + 2 sum_k c_k))`` (``c_k`` the correlation of the quantity at lag ``k``):
for ``rho = 0.9`` and blocks of ``4 tau = 38`` values, 6 % for ``G`` and 12 % for ``chi``
(``c_k = rho^4k``, ``rho^2k``), 3 % and 6 % in the error; with a scatter of 1 %
(``B`` = 5000), 12 % holds both beyond four standard deviations.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from flocking import Model
from flocking.analysis import PolarOrder
from flocking.config import RunConfig
from flocking.observables import polar_moments
from flocking.sweep.point import summarise

T = 200_000


def ar1(rho: float, seed: int, length: int = T) -> np.ndarray:
    """A stationary Gaussian AR(1) series of unit variance and lag-one correlation ``rho``."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(length) * math.sqrt(1.0 - rho * rho)
    x = np.empty(length)
    x[0] = rng.standard_normal()
    for t in range(1, length):
        x[t] = rho * x[t - 1] + noise[t]
    return x


def bernoulli(p: float, seed: int, length: int = T) -> np.ndarray:
    return (np.random.default_rng(seed).random(length) < p).astype(float)


def order(series: np.ndarray, n: int) -> PolarOrder:
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # these series are stationary: no warning either
        return PolarOrder().compute(series, n=n)


# -- values: series whose moments are exact ------------------------------------------------------

#: (series, n, <phi>, <phi^2>, <phi^4>, chi, G): two-valued series and a constant one, by hand
EXACT = {
    # one in four is 1: <phi^2> = <phi^4> = 1/4, G = 1 - (1/4) / (3/16) = -1/3
    "one-in-four": ([1.0, 0.0, 0.0, 0.0] * 5, 10, 0.25, 0.25, 0.25, 10 * (0.25 - 0.0625), -1 / 3),
    # half 0.2, half 0.6: <phi^2> = 0.2, <phi^4> = (0.0016 + 0.1296) / 2 = 0.0656, G = 1 - 0.0656 / 0.12 = 34/75
    "two-levels": ([0.2, 0.6] * 8, 100, 0.4, 0.2, 0.0656, 100 * (0.2 - 0.16), 34 / 75),
    # a constant: G = 1 - 1/3 = 2/3, no fluctuation
    "constant": ([0.7] * 12, 50, 0.7, 0.49, 0.7**4, 0.0, 2 / 3),
}


@pytest.mark.parametrize("name", EXACT)
def test_polar_moments_of_series_with_exact_moments(name):
    series, n, mean, phi2, phi4, chi, binder = EXACT[name]
    m = polar_moments(np.array(series), n)
    assert m["mean"] == pytest.approx(mean, abs=1e-14)
    assert m["phi2"] == pytest.approx(phi2, abs=1e-14) and m["phi4"] == pytest.approx(phi4, abs=1e-14)
    assert m["susceptibility"] == pytest.approx(chi, abs=1e-12)
    assert m["binder"] == pytest.approx(binder, abs=1e-12)


@pytest.mark.parametrize("name", EXACT)
def test_polar_order_and_a_sweep_record_give_the_same_exact_moments(name):
    series, n, mean, phi2, phi4, chi, binder = EXACT[name]
    op = PolarOrder().compute(np.array(series), n=n)
    assert (op.mean, op.phi2, op.phi4) == pytest.approx((mean, phi2, phi4), abs=1e-14)
    assert op.susceptibility == pytest.approx(chi, abs=1e-12) and op.binder == pytest.approx(binder, abs=1e-12)
    # a sweep's record of a run whose polar order after the transient was this series
    cfg = RunConfig(Model(n=n, box=10.0), steps=len(series))
    record = summarise({"time_series": False}, cfg, series, len(series))
    assert record["moments"]["susceptibility"] == pytest.approx(chi, abs=1e-12)
    assert record["moments"]["binder"] == pytest.approx(binder, abs=1e-12)
    assert record["moments"]["phi4"] == pytest.approx(phi4, abs=1e-14)


def test_binder_cumulant_of_a_zero_mean_gaussian_is_zero():
    """``<x^4> = 3 <x^2>^2``: G = 0, within its standard error ``sqrt(8 / (3 T))``."""
    x = np.random.default_rng(3).standard_normal(T)
    assert abs(polar_moments(x, 1)["binder"]) < 4 * math.sqrt(8 / (3 * T))


# -- error bars: series of known statistics ------------------------------------------------------


@pytest.mark.parametrize("p", [0.5, 0.2])
def test_error_bars_of_a_bernoulli_series(p):
    op = order(bernoulli(p, seed=int(10 * p)), n=1)
    error_g = math.sqrt(p * (1 - p) / T) / (3 * p * p)
    assert abs(op.binder - (1 - 1 / (3 * p))) < 4 * error_g
    assert op.binder_error == pytest.approx(error_g, rel=0.05)
    # phi^4 = phi^2 = phi: each the mean of a Bernoulli variable
    for error in (op.mean_error, op.phi2_error, op.phi4_error):
        assert error == pytest.approx(math.sqrt(p * (1 - p) / T), rel=0.05)


def test_error_bars_of_independent_gaussian_values():
    n, s = 300, 0.02
    op = order(s * np.random.default_rng(4).standard_normal(T), n=n)
    assert op.tau == pytest.approx(0.5, abs=0.05)
    assert op.mean_error == pytest.approx(s / math.sqrt(T), rel=0.05)
    assert op.phi2_error == pytest.approx(s**2 * math.sqrt(2 / T), rel=0.05)  # Var x^2 = 2 s^4
    assert op.phi4_error == pytest.approx(s**4 * math.sqrt(96 / T), rel=0.05)  # Var x^4 = 105 s^8 - 9 s^8
    assert op.susceptibility_error == pytest.approx(n * s**2 * math.sqrt(2 / T), rel=0.05)
    assert op.binder_error == pytest.approx(math.sqrt(8 / (3 * T)), rel=0.05)


def test_error_bars_of_a_correlated_gaussian_series():
    """AR(1) with rho = 0.9: the errors grow by the factors the correlations give
    (``(1 + rho^k) / (1 - rho^k)`` under the root, k = 1, 2, 4), 4.4, 3.1 and 2.2 times the
    errors of as many independent values; blocks that ignored the correlations fail."""
    rho, n = 0.9, 1000
    op = order(ar1(rho, seed=5), n=n)
    growth = lambda k: (1 + rho**k) / (1 - rho**k)  # noqa: E731
    assert op.mean_error == pytest.approx(math.sqrt(growth(1) / T), rel=0.12)
    assert op.susceptibility_error == pytest.approx(n * math.sqrt(2 / T * growth(2)), rel=0.12)
    error_g = math.sqrt(8 / (3 * T) * growth(4))
    assert op.binder_error == pytest.approx(error_g, rel=0.12)
    assert abs(op.binder) < 4 * error_g


def test_a_sweep_record_keeps_the_jackknife_errors():
    p = 0.5
    series = bernoulli(p, seed=6)
    cfg = RunConfig(Model(n=1, box=10.0), steps=T)
    record = summarise({"time_series": False}, cfg, series, T)
    assert record["errors"]["binder"] == pytest.approx(math.sqrt(p * (1 - p) / T) / (3 * p * p), rel=0.05)
    assert record["errors"]["phi4"] == pytest.approx(math.sqrt(p * (1 - p) / T), rel=0.05)
