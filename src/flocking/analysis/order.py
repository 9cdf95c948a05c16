"""Polar order: its time series and its moments over a window, with honest error bars.

Successive values of ``phi`` are correlated, so the error of a time average is not
``std / sqrt(T)``. The error of ``<phi>`` uses the integrated autocorrelation time
``tau`` (Sokal's automatic window, ``W >= 5 tau``): ``err^2 = 2 tau var / T``. The
errors of ``<phi^2>``, ``<phi^4>``, ``chi`` and ``G`` come from a jackknife over blocks
of at least ``4 tau`` steps (and at most ``T / 16``). A window whose two halves differ
by more than four errors (``sqrt(2)`` times the smaller error of a half's mean: a
transient inflates the error of its own half) triggers a warning: it has likely not
equilibrated.

``start="auto"`` finds the transient (Chodera's rule, J. Chem. Theory Comput. 12, 1799
(2016)): of the first steps ``t0`` in 0, T/256, ..., T/2, the one that leaves the most
effectively independent samples ``(T - t0) / (2 tau(t0))``. A steady state keeps almost
everything; a transient, which inflates ``tau`` of every window that holds it, is cut.
The rule weighs bias against variance: what it keeps of the transient's tail lies within
the error bar it inflates.
If the window found still drifts (or the series is under 64 values), the second half of
the run is kept instead; ``window_rule`` says which.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> op = PolarOrder().compute(0.5 + 0.01 * rng.standard_normal(4000), n=1000)
>>> round(op.mean, 2), op.mean_error < 0.001, round(op.tau, 0)
(0.5, True, 1.0)
"""

from __future__ import annotations

import csv
import math
import numbers
import os
import warnings

import numpy as np

from ..model import ParameterError
from ..observables import polar_moments
from . import _input
from ._base import Analysis, format_value, legend, positive, result


def autocorrelation(x: np.ndarray) -> np.ndarray:
    """Normalised autocorrelation function of a series (FFT, O(T log T))."""
    x = np.asarray(x, float) - np.mean(x)
    t = len(x)
    f = np.fft.rfft(x, 2 * t)
    acf = np.fft.irfft(f * np.conj(f))[:t]
    return acf / acf[0] if acf[0] > 0 else np.r_[1.0, np.zeros(t - 1)]


def integrated_time(x, c: float = 5.0) -> float:
    """Integrated autocorrelation time ``tau = 1/2 + sum_{t>=1} rho(t)`` with Sokal's window:
    the smallest ``W`` with ``W >= c tau(W)``. 1/2 for independent values (so that
    ``err^2 = 2 tau var / T``).

    >>> rng = np.random.default_rng(1)
    >>> x = np.zeros(20000)
    >>> for t in range(1, len(x)):
    ...     x[t] = 0.8 * x[t - 1] + rng.standard_normal()
    >>> bool(abs(integrated_time(x) - 0.5 * 1.8 / 0.2) < 1.0)
    True
    """
    rho = autocorrelation(x)
    taus = 0.5 + np.cumsum(rho[1:])
    windows = np.arange(1, len(rho))
    ok = windows >= c * taus
    w = int(np.argmax(ok)) if ok.any() else len(taus) - 1
    return float(max(taus[w], 0.5)) if len(taus) else 0.5


def _jackknife(values: np.ndarray, block: int, n: int) -> dict[str, float]:
    """Jackknife errors of the moments over ``len(values) // block`` blocks."""
    nb = len(values) // block
    if nb < 2:
        return {k: float("nan") for k in ("mean", "phi2", "phi4", "susceptibility", "binder")}
    v = values[len(values) - nb * block:].reshape(nb, block)
    s1, s2, s4 = v.sum(1), (v**2).sum(1), (v**4).sum(1)
    total = nb * block - block
    m1 = (s1.sum() - s1) / total
    m2 = (s2.sum() - s2) / total
    m4 = (s4.sum() - s4) / total
    est = {"mean": m1, "phi2": m2, "phi4": m4, "susceptibility": n * (m2 - m1 * m1),
           "binder": 1.0 - m4 / (3.0 * m2 * m2)}
    return {k: float(math.sqrt((nb - 1) / nb * np.sum((e - e.mean()) ** 2))) for k, e in est.items()}


def transient_end(x: np.ndarray, candidates: int = 128, points: int = 4096) -> int:
    """Index where the transient of ``x`` ends: Chodera's rule over ``candidates`` first
    values up to the middle (see the module). A series longer than ``points`` is first
    averaged in blocks to at most that many values, which keeps a transient and scales
    ``tau`` alike for every candidate.

    >>> x = np.r_[np.linspace(0.0, 0.8, 300), 0.8 + 0.01 * np.random.default_rng(5).standard_normal(2700)]
    >>> 300 <= transient_end(x) <= 320
    True
    """
    block = max(1, -(-len(x) // points))
    y = np.asarray(x, float)[: len(x) // block * block].reshape(-1, block).mean(axis=1)
    t = len(y)
    best, best_eff = 0, -1.0
    for t0 in np.unique(np.linspace(0, t // 2, candidates + 1).astype(int)):
        eff = (t - t0) / (2 * integrated_time(y[t0:]))
        if eff > best_eff:
            best, best_eff = int(t0), eff
    return best * block


def _drift(x: np.ndarray) -> float:
    """(second-half mean - first-half mean) / (sqrt(2) x the smaller error of a half)."""
    half = len(x) // 2
    if half < 4:
        return 0.0
    (e1, _), (e2, _) = _mean_error(x[:half]), _mean_error(x[half:])
    diff = x[half:].mean() - x[:half].mean()
    scale = math.sqrt(2.0) * min(e1, e2)  # a transient inflates its own half's error
    return diff / scale if scale > 0 else (0.0 if diff == 0 else math.copysign(math.inf, diff))


def _auto_window(x: np.ndarray) -> tuple[int, str]:
    """``(first index, rule)`` of the steady window of ``x`` (at least two values)."""
    if len(x) >= 64:
        first = transient_end(x)
        if abs(_drift(x[first:])) <= 4.0:
            return first, "detected"
    return min(len(x) // 2, len(x) - 2), "half the run"


def _mean_error(x: np.ndarray) -> tuple[float, float]:
    tau = integrated_time(x)
    var = float(np.var(x))
    return math.sqrt(2.0 * tau * var / len(x)), tau


def read_observables(path) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, phi)`` from an ``observables.csv`` (columns ``step,polar_order``)."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows or "polar_order" not in rows[0]:
        raise ParameterError(f"system: {os.fspath(path)!r} has no polar_order column")
    col, scol = rows[0].index("polar_order"), rows[0].index("step") if "step" in rows[0] else None
    body = [r for r in rows[1:] if len(r) == len(rows[0])]
    phi = np.array([float(r[col]) for r in body])
    steps = np.array([int(r[scol]) for r in body]) if scol is not None else np.arange(len(phi))
    return steps, phi


class PolarOrder(Analysis):
    """Polar order ``phi(t) = |sum_i u_i| / N`` and its statistics over a window.

    Parameters
    ----------
    start:
        The window: the first step kept (``int``), the fraction of the series to discard
        when ``0 < start < 1``, or ``"auto"``: the end of the transient, detected (see
        the module). Default: keep everything.
    dt:
        Time step of the data (default: the run's stored ``dt``, else 1).

    ``compute(system, n=None)`` accepts a run folder (its ``observables.csv``: every
    step), an ``observables.csv`` path, a 1D array of values (``n`` is then needed for
    the susceptibility; otherwise it is NaN), or anything with frames (a trajectory, a
    GSD path, frames: one value per frame).
    """

    _keys = ("n", "samples", "window_start", "window_rule", "mean", "mean_error", "phi2", "phi2_error", "phi4",
             "phi4_error", "susceptibility", "susceptibility_error", "binder", "binder_error", "tau", "tau_time",
             "drift", "equilibrated", "suggested_start", "dt_used")

    def __init__(self, start=None, dt=None):
        if start != "auto":
            _input.window_start(start, [0], 1)  # validate
        self.start = start
        self.dt = positive("dt", dt, allow_none=True)

    def parameters(self) -> dict:
        return {"start": self.start, "dt": self.dt}

    steps = result("steps", "Step of each value of the whole series.")
    times = result("times", "Time of each value: steps * dt.")
    series = result("series", "The whole time series phi(t).")
    window = result("window", "Boolean mask of the values in the window.")
    window_start = result("window_start", "First step of the window.")
    window_rule = result("window_rule", "How the window was chosen: 'all', 'given', 'detected' or 'half the run'.")
    n = result("n", "Number of particles (None when unknown).")
    samples = result("samples", "Number of values in the window.")
    mean = result("mean", "<phi> over the window.")
    mean_error = result("mean_error", "Error of <phi> (integrated autocorrelation time).")
    phi2 = result("phi2", "<phi^2>.")
    phi2_error = result("phi2_error", "Error of <phi^2> (block jackknife).")
    phi4 = result("phi4", "<phi^4>.")
    phi4_error = result("phi4_error", "Error of <phi^4> (block jackknife).")
    susceptibility = result("susceptibility", "chi = N (<phi^2> - <phi>^2).")
    susceptibility_error = result("susceptibility_error", "Error of chi (block jackknife).")
    binder = result("binder", "Binder cumulant G = 1 - <phi^4> / (3 <phi^2>^2).")
    binder_error = result("binder_error", "Error of G (block jackknife).")
    tau = result("tau", "Integrated autocorrelation time of phi in the window, in samples.")
    tau_time = result("tau_time", "tau in the model's time: tau x the median step between samples x dt.")
    drift = result("drift", "(second-half mean - first-half mean) / (sqrt(2) x the smaller half error).")
    equilibrated = result("equilibrated", "False when |drift| > 4.")
    suggested_start = result("suggested_start", "A later first step to try when not equilibrated (else None).")
    dt_used = result("dt_used", "Time step used for times and tau_time.")

    def compute(self, system, n: int | None = None) -> PolarOrder:
        steps, phi, n, model = self._series(system, n)
        if phi.size < 2:
            raise ParameterError(f"system: holds {phi.size} polar order value{'' if phi.size == 1 else 's'}; "
                                 "statistics need at least 2 (a run of at least one step)")
        if not np.all(np.isfinite(phi)):
            raise ParameterError("system: the polar order series holds non-finite values")
        if self.start == "auto":
            first, rule = _auto_window(phi)
        else:
            first = _input.window_start(self.start, steps, len(phi))
            rule = "all" if self.start is None else "given"
        window = np.zeros(len(phi), bool)
        window[first:] = True
        x = phi[window]
        if x.size < 2:
            raise ParameterError(f"start: leaves {x.size} value(s) in the window; at least 2 are needed "
                                 f"(the series ends at step {int(steps[-1])})")
        moments = polar_moments(x, 1 if n is None else n)
        if n is None:
            moments["susceptibility"] = float("nan")
        mean_error, tau = _mean_error(x)
        block = int(min(max(math.ceil(4 * tau), 1), max(len(x) // 16, 1)))
        errors = _jackknife(x, block, 1 if n is None else n)
        if n is None:
            errors["susceptibility"] = float("nan")
        drift = _drift(x)
        equilibrated = abs(drift) <= 4.0
        suggested = None
        if not equilibrated:
            suggested = int(steps[first + _auto_window(x)[0]])
            warnings.warn(f"PolarOrder: the window does not look equilibrated: the mean of its second half "
                          f"differs from the first by {abs(drift):.1f} errors; discard more (start={suggested})",
                          RuntimeWarning, stacklevel=2)
        dt = _input.time_step(self.dt, model)
        spacing = float(np.median(np.diff(steps[window])))
        self._store(steps=steps, times=steps * dt, series=phi, window=window, window_start=int(steps[first]),
                    window_rule=rule, n=n, samples=int(x.size), mean=moments["mean"], mean_error=mean_error,
                    phi2=moments["phi2"], phi2_error=errors["phi2"], phi4=moments["phi4"], phi4_error=errors["phi4"],
                    susceptibility=moments["susceptibility"], susceptibility_error=errors["susceptibility"],
                    binder=moments["binder"], binder_error=errors["binder"], tau=tau, tau_time=tau * spacing * dt,
                    drift=float(drift), equilibrated=bool(equilibrated), suggested_start=suggested, dt_used=dt)
        return self

    @staticmethod
    def _series(system, n):
        """``(steps, phi, n, model)`` of any accepted system."""
        if n is not None and (isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1):
            raise ParameterError(f"n: must be a whole number >= 1 (got {n!r})")
        if isinstance(system, (str, os.PathLike)):
            path = os.fspath(system)
            csv_path = os.path.join(path, "observables.csv") if os.path.isdir(path) else path
            if os.path.isdir(path) and not os.path.exists(csv_path):
                csv_path = None
            if csv_path is not None and csv_path.endswith(".csv"):
                if not os.path.exists(csv_path):
                    raise ParameterError(f"system: no such file {csv_path!r}")
                steps, phi = read_observables(csv_path)
                model = _input.model_of(path) if os.path.isdir(path) else None
                if n is None and model is not None:
                    n = model.n
                return steps, phi, n, model
        if isinstance(system, (np.ndarray, list)) and np.ndim(system) == 1 and len(system) and \
                isinstance(np.asarray(system).flat[0], numbers.Real):
            phi = np.asarray(system, dtype=float)
            return np.arange(len(phi)), phi, n, None
        frames = _input.as_frames(system)
        steps, phi = frames.steps, []
        for f in frames:
            u = f.require_headings("PolarOrder")
            phi.append(np.linalg.norm(u.sum(axis=0)) / f.n)
            n = f.n if n is None else n
        return np.asarray(steps), np.asarray(phi), n, frames.model

    def plot(self, ax=None, theme=None):
        """The series against time, the window shaded, and the mean with its error."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        ax.plot(self.times, self.series, lw=0.8, color=colours[0], label=r"$\varphi(t)$")
        w = self.times[self.window]
        ax.axvspan(w[0], w[-1], color=colours[0], alpha=0.12, lw=0, label=f"window ({self.window_rule})")
        ax.axhline(self.mean, color=colours[1], lw=1.2,
                   label=rf"$\langle\varphi\rangle = {format_value(self.mean, self.mean_error)}$")
        style.label_axes(ax, "time", "phi")
        legend(ax, theme)
        return ax
