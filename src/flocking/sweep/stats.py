"""Statistics across the runs of a sweep: replicas combined, finite-size scaling.

Replicas. At one grid point, replica ``i`` measures ``x_i = mu + e_i``: the runs are
independent, and ``e_i`` has a variance ``sigma_i^2`` that the run itself estimates as
``s_i^2`` from its autocorrelation time (:class:`flocking.analysis.PolarOrder`; a block
jackknife for ``chi`` and ``G``). :func:`combine` returns the plain mean ``m = sum x_i / R``
(equal weights: the replicas are equally long runs of one process, so the ``sigma_i`` agree
and only their estimates scatter; weighting by ``1 / s_i^2`` would favour the runs whose
fluctuations happened to be small, and bias the mean toward them) and its error
``sqrt(max(V_w, V_b))`` with

- ``V_w = sum s_i^2 / R^2``: the variance of ``m`` from the errors within the runs,
  ``Var m = sum sigma_i^2 / R^2``, precise when the runs are long (``T / tau`` independent
  samples each), and never 0 because replicas happen to agree;
- ``V_b = sum (x_i - m)^2 / (R (R - 1))``: the same variance from the scatter between
  replicas (the squared standard error), with only ``R - 1`` degrees of freedom.

When the runs sample the same stationary state and the ``s_i`` are right, both estimate
``Var m`` and ``V_b / V_w`` follows ``chi^2_{R-1} / (R - 1)``. When they do not (runs stuck
in different states near a discontinuous transition, runs that had not settled), the
within-run errors are too small and the scatter between replicas shows it: ``V_b`` is
larger and is used. ``max(V_w, V_b)`` is ``V_w`` times the Birge ratio ``max(1, V_b / V_w)``,
the rule :func:`flocking.analysis.base.fit_line` applies to the residuals of a fit.
Its coverage, for Gaussian errors of equal variance and exact ``s_i``, is
``P(|m - mu| <= error) = E[erf(sqrt(max(1, Q) / 2))]`` with ``Q ~ chi^2_{R-1} / (R - 1)``
(``m`` is independent of the sample variance): 0.733 for ``R = 2``, 0.731 for 3, 0.725 for
5, toward 0.683 for many replicas; the standard error alone covers only 0.50, 0.58, 0.63
(Student's t with ``R - 1`` degrees of freedom). One replica: ``V_w`` alone. No within-run
error (results of an older flocking): ``V_b`` alone.

>>> mean, error = combine([0.50, 0.50], [0.01, 0.01])  # agreeing replicas keep their errors
>>> float(mean), round(float(error), 5)
(0.5, 0.00707)
>>> mean, error = combine([0.2, 0.8], [0.01, 0.01])    # disagreeing ones: the scatter wins
>>> float(mean), round(float(error), 5)
(0.5, 0.3)
"""

from __future__ import annotations

import math

import numpy as np

from ..analysis.base import fit_line


def combine(values, errors, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Mean over ``axis`` (the replicas) of ``values`` and its error, from each replica's
    own ``errors`` and the scatter between replicas (see the module's text).

    NaN values (failed or missing runs) are left out; a NaN error of a run that has a
    value means "unknown", and leaves the scatter alone. Where no value is left, the mean
    and error are NaN.
    """
    values = np.asarray(values, dtype=float)
    errors = np.broadcast_to(np.asarray(errors, dtype=float), values.shape)
    ok = np.isfinite(values)
    count = ok.sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok, values, 0.0).sum(axis=axis) / count
        within = np.sqrt(np.where(ok, errors**2, 0.0).sum(axis=axis)) / count
        within = np.where((ok & ~np.isfinite(errors)).any(axis=axis), np.nan, within)
        deviation = np.where(ok, values - np.expand_dims(mean, axis), 0.0)
        between = np.sqrt((deviation**2).sum(axis=axis) / (count * (count - 1)))
        between = np.where(count > 1, between, np.nan)
    error = np.fmax(within, between)
    return mean, np.where(count > 0, error, np.nan)


def peak(x, mean, error) -> tuple[float, float, float]:
    """``(x, value, error)`` at the largest finite ``mean`` (the susceptibility's peak on
    the grid: its true maximum may lie between grid points).

    >>> peak([1.0, 2.0, 3.0], [0.5, 2.0, 1.0], [0.1, 0.3, 0.1])
    (2.0, 2.0, 0.3)
    """
    mean = np.asarray(mean, dtype=float)
    if not np.isfinite(mean).any():
        return math.nan, math.nan, math.nan
    i = int(np.nanargmax(mean))
    return float(np.asarray(x, dtype=float)[i]), float(mean[i]), float(np.asarray(error, dtype=float)[i])


def crossings(x, a, b) -> list[float]:
    """The ``x`` where two curves sampled at the same ``x`` cross (linear between
    samples, where ``b - a`` changes sign).

    >>> crossings([0.0, 1.0, 2.0], [0.6, 0.5, 0.3], [0.7, 0.5, 0.2])
    [1.0]
    >>> crossings([0.0, 1.0], [0.0, 1.0], [1.0, 0.0])
    [0.5]
    """
    x = np.asarray(x, dtype=float)
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    out = []
    for i in range(len(x) - 1):
        d0, d1 = d[i], d[i + 1]
        if not (np.isfinite(d0) and np.isfinite(d1)):
            continue
        if d0 == 0.0 and (i == 0 or d[i - 1] != 0.0):
            out.append(float(x[i]))
        elif d0 * d1 < 0.0:
            out.append(float(x[i] - d0 * (x[i + 1] - x[i]) / (d1 - d0)))
    if len(d) and d[-1] == 0.0 and (len(d) == 1 or d[-2] != 0.0):
        out.append(float(x[-1]))
    return out


def exponent(sizes, values, errors) -> tuple[float, float, float]:
    """``(slope, intercept, slope_error)`` of ``ln values`` against ``ln sizes``, weighted
    by the relative errors (:func:`~flocking.analysis.base.fit_line`: the formal error,
    scaled up when the points scatter more than their errors allow).

    >>> slope, _, err = exponent([100, 400, 1600], [2.0, 4.0, 8.0], [0.2, 0.4, 0.8])
    >>> round(slope, 12), err > 0
    (0.5, True)
    """
    sizes, values, errors = (np.asarray(v, dtype=float) for v in (sizes, values, errors))
    ok = np.isfinite(values) & (values > 0) & (sizes > 0)
    sigma = np.where(np.isfinite(errors) & (errors > 0), errors / np.where(values > 0, values, 1.0), np.nan)
    if ok.sum() < 2:
        return math.nan, math.nan, math.nan
    if np.isfinite(sigma[ok]).all():
        return fit_line(np.log(sizes[ok]), np.log(values[ok]), sigma[ok])
    return fit_line(np.log(sizes[ok]), np.log(values[ok]))


__all__ = ["combine", "crossings", "exponent", "peak"]
