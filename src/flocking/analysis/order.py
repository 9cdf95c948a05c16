"""Order parameters: the polar order (of the flock or of one species) and the nematic
order, their time series and their moments over a window, with honest error bars.

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
from typing import NamedTuple

import numpy as np

from ..model import ParameterError
from ..observables import polar_moments
from . import snapshots
from .base import Analysis, format_value, legend, positive, result


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


class Histogram(NamedTuple):
    """The distribution of an order parameter over a window: ``counts[k]`` values lie in
    ``[edges[k], edges[k + 1])`` (the last bin holds 1 too); ``density`` is ``counts``
    divided by ``samples x bin width``, so that it integrates to 1."""

    edges: np.ndarray
    counts: np.ndarray
    density: np.ndarray


def histogram_bins(bins) -> int:
    """``bins`` checked: a whole number >= 1 (:class:`ParameterError` otherwise)."""
    if isinstance(bins, bool) or not isinstance(bins, numbers.Integral) or bins < 1:
        raise ParameterError(f"bins: must be a whole number >= 1 (got {bins!r})")
    return int(bins)


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
    with np.errstate(invalid="ignore", divide="ignore"):  # a series of zeros has no Binder cumulant
        binder = 1.0 - m4 / (3.0 * m2 * m2)
    est = {"mean": m1, "phi2": m2, "phi4": m4, "susceptibility": n * (m2 - m1 * m1), "binder": binder}
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


def read_column(path, column: str = "polar_order") -> tuple[np.ndarray, np.ndarray] | None:
    """``(steps, values)`` of one column of an ``observables.csv`` (``step,polar_order``,
    then ``polar_order_<species>`` and ``nematic_order`` where the run records them), or
    ``None`` when the file has no such column."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows or column not in rows[0]:
        return None
    col, scol = rows[0].index(column), rows[0].index("step") if "step" in rows[0] else None
    body = [r for r in rows[1:] if len(r) == len(rows[0])]
    values = np.array([float(r[col]) for r in body])
    steps = np.array([int(r[scol]) for r in body]) if scol is not None else np.arange(len(values))
    return steps, values


def csv_columns(path) -> list[str]:
    """The header of an ``observables.csv``."""
    with open(path, newline="", encoding="utf-8") as f:
        return next(csv.reader(f), [])


def nematic_order(headings: np.ndarray) -> float:
    """Nematic order of unit ``headings`` (N, d) (docs/model.md, Extensions: Observables): in 2D
    ``|sum_i exp(2 i theta_i)| / N``, in 3D the largest eigenvalue of
    ``Q = (3/2) <u u^T> - (1/2) I``. 1 for headings along one axis, either way; near 0
    (of order ``N^-1/2``) for isotropic ones. In 2D it is also the largest eigenvalue of
    ``2 <u u^T> - I``.

    >>> nematic_order(np.array([[1.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]]))
    1.0
    >>> round(nematic_order(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])), 12)
    0.0
    """
    u = np.asarray(headings, dtype=np.float64)
    if u.shape[1] == 2:
        return float(np.hypot(np.mean(u[:, 0] * u[:, 0] - u[:, 1] * u[:, 1]), np.mean(2.0 * u[:, 0] * u[:, 1])))
    q = 1.5 * (u.T @ u) / len(u) - 0.5 * np.eye(3)
    return float(np.linalg.eigvalsh(q)[-1])


def polar_order(headings: np.ndarray) -> float:
    """``|sum_i u_i| / N`` of unit ``headings`` (N, d)."""
    return float(np.linalg.norm(headings.sum(axis=0)) / len(headings))


def order_notes(moments: dict, errors: dict, n, samples: int, block: int) -> list[str]:
    """Why any moment or error of a window is NaN."""
    notes = []
    if n is None:
        notes.append("susceptibility, susceptibility_error: NaN, the number of particles is not known (give n)")
    if math.isnan(moments["binder"]):
        notes.append("binder, binder_error: NaN, the order is 0 throughout the window (<phi^2> = 0)")
    if samples // block < 2:
        nan = [f"{key}_error" for key in ("phi2", "phi4", "susceptibility", "binder")]
        notes.append(f"{', '.join(nan)}: NaN, the window's {samples} values make fewer than two blocks of "
                     f"{block} (at least 4 tau) for the jackknife")
    return notes


class _Order(Analysis):
    """An order parameter's time series and its statistics over a window (see the module);
    subclasses name the quantity, its ``observables.csv`` column and its value for a frame."""

    _keys = ("species", "n", "samples", "window_start", "window_rule", "mean", "mean_error", "phi2", "phi2_error",
             "phi4", "phi4_error", "susceptibility", "susceptibility_error", "binder", "binder_error", "tau",
             "tau_time", "drift", "equilibrated", "suggested_start", "dt_used")
    #: the column of observables.csv (for the whole flock; ``<column>_<species>`` per species)
    _column = ""
    #: mathtext symbol and axis label of the plots
    _symbol = ""
    _axis_label = ""

    def __init__(self, start=None, dt=None, species: str | None = None):
        if start != "auto":
            snapshots.window_start(start, [0], 1)  # validate
        if species is not None and (not isinstance(species, str) or not species):
            raise ParameterError(f"species: must be the name of a species (got {species!r})")
        self.start = start
        self.dt = positive("dt", dt, allow_none=True)
        self.species = species

    def parameters(self) -> dict:
        return {"start": self.start, "dt": self.dt, "species": self.species}

    steps = result("steps", "Step of each value of the whole series.")
    times = result("times", "Time of each value: steps * dt.")
    series = result("series", "The whole time series.")
    window = result("window", "Boolean mask of the values in the window.")
    window_start = result("window_start", "First step of the window.")
    window_rule = result("window_rule", "How the window was chosen: 'all', 'given', 'detected' or 'half the run'.")
    n = result("n", "Number of particles measured (of the species when one is chosen; None when unknown).")
    samples = result("samples", "Number of values in the window.")
    mean = result("mean", "Mean over the window.")
    mean_error = result("mean_error", "Error of the mean (integrated autocorrelation time).")
    phi2 = result("phi2", "Mean of the square over the window.")
    phi2_error = result("phi2_error", "Error of phi2 (block jackknife).")
    phi4 = result("phi4", "Mean of the fourth power over the window.")
    phi4_error = result("phi4_error", "Error of phi4 (block jackknife).")
    susceptibility = result("susceptibility", "chi = n (phi2 - mean^2).")
    susceptibility_error = result("susceptibility_error", "Error of chi (block jackknife).")
    binder = result("binder", "Binder cumulant G = 1 - phi4 / (3 phi2^2).")
    binder_error = result("binder_error", "Error of G (block jackknife).")
    tau = result("tau", "Integrated autocorrelation time in the window, in samples.")
    tau_time = result("tau_time", "tau in the model's time: tau x the median step between samples x dt.")
    drift = result("drift", "(second-half mean - first-half mean) / (sqrt(2) x the smaller half error).")
    equilibrated = result("equilibrated", "False when |drift| > 4.")
    suggested_start = result("suggested_start", "A later first step to try when not equilibrated (else None).")
    dt_used = result("dt_used", "Time step used for times and tau_time.")

    @staticmethod
    def _value(headings: np.ndarray) -> float:
        raise NotImplementedError

    def compute(self, system, n: int | None = None):
        steps, phi, n, model = self._series(system, n)
        name = type(self).__name__
        if phi.size < 2:
            of = "" if self.species is None else f" of species {self.species}"
            raise ParameterError(f"system: holds {phi.size} {self._column.replace('_', ' ')} "
                                 f"value{'' if phi.size == 1 else 's'}{of}; statistics need at least 2 (a run of "
                                 "at least one step)")
        if not np.all(np.isfinite(phi)):
            raise ParameterError(f"system: the {self._what()} series holds non-finite values")
        if self.start == "auto":
            first, rule = _auto_window(phi)
        else:
            first = snapshots.window_start(self.start, steps, len(phi))
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
            of = "" if self.species is None else f" of species {self.species}"
            warnings.warn(f"{name}{of}: the window does not look equilibrated: the mean of its second half "
                          f"differs from the first by {abs(drift):.1f} errors; discard more (start={suggested})",
                          RuntimeWarning, stacklevel=2)
        dt = snapshots.time_step(self.dt, model)
        spacing = float(np.median(np.diff(steps[window])))
        self._store(steps=steps, times=steps * dt, series=phi, window=window, window_start=int(steps[first]),
                    window_rule=rule, species=self.species, n=n, samples=int(x.size), mean=moments["mean"],
                    mean_error=mean_error, phi2=moments["phi2"], phi2_error=errors["phi2"], phi4=moments["phi4"],
                    phi4_error=errors["phi4"], susceptibility=moments["susceptibility"],
                    susceptibility_error=errors["susceptibility"], binder=moments["binder"],
                    binder_error=errors["binder"], tau=tau, tau_time=tau * spacing * dt, drift=float(drift),
                    equilibrated=bool(equilibrated), suggested_start=suggested, dt_used=dt,
                    notes=order_notes(moments, errors, n, len(x), block))
        return self

    def histogram(self, bins: int = 50) -> Histogram:
        """The distribution of the values in the window: ``bins`` equal bins over [0, 1],
        the range of the order (values a rounding error outside it are counted at its
        ends). Bimodal near a discontinuous transition, where the run switches between an
        ordered and a disordered state.

        >>> op = PolarOrder().compute(np.array([0.05, 0.1, 0.12, 0.8, 0.85, 1.0]))
        >>> op.histogram(bins=4).counts.tolist(), op.histogram(bins=4).density.tolist()
        ([3, 0, 0, 3], [2.0, 0.0, 0.0, 2.0])
        """
        bins = histogram_bins(bins)
        x = np.clip(self.series[self.window], 0.0, 1.0)
        counts, edges = np.histogram(x, bins=bins, range=(0.0, 1.0))
        return Histogram(edges, counts, counts / (x.size * (1.0 / bins)))

    def plot_histogram(self, ax=None, theme=None, bins: int = 50):
        """The distribution of the values in the window (:meth:`histogram`, as a density),
        with the mean over the window and its error."""
        from ..viz import style

        hist = self.histogram(bins)
        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        symbol = self._symbol_of()
        ax.stairs(hist.density, hist.edges, fill=True, color=colours[0], alpha=0.35)
        ax.stairs(hist.density, hist.edges, color=colours[0], lw=1.0,
                  label=f"{self.samples} values, {len(hist.counts)} bins")
        ax.axvline(self.mean, color=colours[1], lw=1.4, ls="--",
                   label=rf"$\langle {symbol}\rangle = {format_value(self.mean, self.mean_error)}$")
        style.label_axes(ax, self._axis_label, "probability density")
        legend(ax, theme)
        return ax

    def _what(self) -> str:
        quantity = self._column.replace("_", " ")
        return quantity if self.species is None else f"{quantity} of species {self.species}"

    def _series(self, system, n):
        """``(steps, values, n, model)`` of any accepted system."""
        if n is not None and (isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1):
            raise ParameterError(f"n: must be a whole number >= 1 (got {n!r})")
        column = self._column if self.species is None else f"{self._column}_{self.species}"
        if isinstance(system, (str, os.PathLike)):
            path = os.fspath(system)
            folder = os.path.isdir(path)
            csv_path = os.path.join(path, "observables.csv") if folder else path
            if csv_path.endswith(".csv") and (os.path.exists(csv_path) or not folder):
                if not os.path.exists(csv_path):
                    raise ParameterError(f"system: no such file {csv_path!r}")
                model = snapshots.model_of(path) if folder else None
                self._check_species(model.species_names if model is not None else None)
                read = read_column(csv_path, column)
                if read is not None:
                    if n is None and model is not None:
                        n = model.n if self.species is None else \
                            model.species_counts[model.species_names.index(self.species)]
                    return read[0], read[1], n, model
                if not folder or not os.path.exists(os.path.join(path, "trajectory.gsd")):
                    raise ParameterError(f"system: {csv_path!r} has no {column} column"
                                         + ("" if folder else "; give the run folder or its trajectory"))
        elif _is_series(system):
            if self.species is not None:
                raise ParameterError("species: a series of values holds no species; give a run or its frames")
            values = np.asarray(system, dtype=float)
            return np.arange(len(values)), values, n, None
        frames = snapshots.as_frames(system)
        self._check_species(frames.model.species_names if frames.model is not None else None)
        values = []
        for f in frames:
            u = f.require_headings(type(self).__name__)
            if self.species is not None:
                u = u[f.members(self.species)]
                if len(u) == 0:
                    raise ParameterError(f"system: frame at step {f.step} holds no particle of species "
                                         f"{self.species}")
            values.append(self._value(u))
            n = len(u) if n is None else n
        return np.asarray(frames.steps), np.asarray(values), n, frames.model

    def _check_species(self, names) -> None:
        if self.species is not None and names is not None and self.species not in names:
            raise ParameterError(f"species: must be one of {', '.join(names)} (got {self.species!r})")

    def _symbol_of(self) -> str:
        """The quantity's mathtext symbol, with the species as a subscript."""
        if self.species is None:
            return self._symbol
        return rf"{self._symbol}_{{\mathrm{{{mathtext_text(self.species)}}}}}"

    def plot(self, ax=None, theme=None):
        """The series against time, the window shaded, and the mean over it (drawn across
        the window only) with its error."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        symbol = self._symbol_of()
        ax.plot(self.times, self.series, lw=0.8, color=colours[0], label=rf"${symbol}(t)$")
        w = self.times[self.window]
        style.shade_window(ax, w[0], w[-1], theme, label=f"window ({self.window_rule})")
        ax.plot(w[[0, -1]], [self.mean, self.mean], color=colours[1], lw=1.4, ls="--",
                label=rf"$\langle {symbol}\rangle = {format_value(self.mean, self.mean_error)}$")
        style.label_axes(ax, "time", self._axis_label)
        legend(ax, theme)
        return ax


def _is_series(system) -> bool:
    """Whether ``system`` is a 1D array or list of numbers (a series of values, not frames)."""
    if isinstance(system, np.ndarray):
        return system.ndim == 1 and system.size > 0 and np.issubdtype(system.dtype, np.number)
    return isinstance(system, list) and len(system) > 0 and all(
        isinstance(x, numbers.Real) and not isinstance(x, bool) for x in system)


def mathtext_text(text: str) -> str:
    r"""``text`` as literal characters inside mathtext's ``\mathrm{}`` (spaces and the
    characters mathtext reads as commands escaped).

    >>> mathtext_text("fast $_1")
    'fast\\ \\$\\_1'
    """
    for char in "\\{}$_^#%&~":
        text = text.replace(char, "\\" + char)
    return text.replace(" ", r"\ ")


class PolarOrder(_Order):
    """Polar order ``phi(t) = |sum_i u_i| / N`` and its statistics over a window.

    Parameters
    ----------
    start
        The window: the first step kept (``int``), the fraction of the series to discard
        when ``0 < start < 1``, or ``"auto"``: the end of the transient, detected (see
        the module). Default: keep everything.
    dt
        Time step of the data (default: the run's stored ``dt``, else 1).
    species
        The name of one species: the polar order of its particles alone
        (``|sum_{i in s} u_i| / N_s``; ``n`` is then ``N_s``). Default: every particle.

    Notes
    -----
    ``compute(system, n=None)`` accepts a run folder (its ``observables.csv``: every
    step; a column ``polar_order_<species>`` for a species), an ``observables.csv`` path,
    a 1D array of values (``n`` is then needed for the susceptibility; otherwise it is
    NaN), or anything with frames (a trajectory, a GSD path, frames: one value per frame;
    a species needs the frames' particle types, GSD's ``particles/typeid``). A run folder
    whose ``observables.csv`` lacks the column is read from its trajectory.
    """

    _column = "polar_order"
    _symbol = r"\varphi"
    _axis_label = "phi"
    _value = staticmethod(polar_order)


class NematicOrder(_Order):
    """Nematic order ``S(t)`` (:func:`nematic_order`: ``|<exp(2 i theta)>|`` in 2D, the
    largest eigenvalue of ``Q = (3/2) <u u^T> - (1/2) I`` in 3D) and its statistics over
    a window, exactly as :class:`PolarOrder` (the same parameters and results: ``mean``,
    ``mean_error``, ``phi2`` = ``<S^2>``, ``susceptibility`` = ``N (<S^2> - <S>^2)``, ...).

    ``S`` is 1 when the headings lie along one axis, however many point each way, so an
    antiparallel state has ``S = 1`` and ``phi = 0``; isotropic headings give ``S`` of
    order ``N^-1/2``. From a run folder it reads the ``nematic_order`` column of
    ``observables.csv`` (written by runs with nematic alignment), else the trajectory.

    >>> u = np.array([[1.0, 0.0]] * 50 + [[-1.0, 0.0]] * 50)
    >>> frames = [(10.0, np.zeros((100, 2)), u), (10.0, np.zeros((100, 2)), -u)]
    >>> s = NematicOrder().compute(frames)
    >>> s.series.tolist(), s.mean, PolarOrder().compute(frames).mean
    ([1.0, 1.0], 1.0, 0.0)
    """

    _column = "nematic_order"
    _symbol = "S"
    _axis_label = r"nematic order $S$"
    _value = staticmethod(nematic_order)


def species_names(system) -> tuple[str, ...]:
    """The species of a run (its stored model), of a GSD file or frames (their particle
    types) or of an ``observables.csv`` (its ``polar_order_<name>`` columns); ``()`` when
    they are unknown.

    >>> species_names([(4.0, np.zeros((2, 2)))])
    ()
    """
    if isinstance(system, (str, os.PathLike)):
        path = os.fspath(system)
        csv_path = os.path.join(path, "observables.csv") if os.path.isdir(path) else path
        if csv_path.endswith(".csv"):
            model = snapshots.model_of(path) if os.path.isdir(path) else None
            if model is not None:
                return model.species_names
            if os.path.exists(csv_path):
                prefix = "polar_order_"
                return tuple(c[len(prefix):] for c in csv_columns(csv_path) if c.startswith(prefix))
            if not os.path.isdir(path):
                raise ParameterError(f"system: no such file {csv_path!r}")
    frames = snapshots.as_frames(system)
    if frames.model is not None:
        return frames.model.species_names
    types = frames[0].types if len(frames) else None
    return () if types is None else types


class PerSpecies(Analysis):
    """An order parameter (:class:`PolarOrder` or :class:`NematicOrder`) of each species
    of a run, over one window.

    ``PerSpecies(PolarOrder(start="auto"))``: the quantity given, with its ``start`` and
    ``dt``, computed for every species. With ``start="auto"`` the window is the one
    detected in the whole flock's series, so that every species is averaged over the
    same steps (each still reports its own ``drift``). ``compute(system)`` takes what the
    quantity takes (a run folder, a GSD file, frames with particle types) and raises when
    the system holds fewer than two species.

    >>> import flocking, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "t.gsd")
    >>> model = flocking.Model(n=200, box=8.0, noise=0.1, species=[{"name": "calm", "fraction": 0.5},
    ...                        {"name": "wild", "fraction": 0.5, "noise": 6.28}], coupling=[[1, 0], [0, 1]])
    >>> sim = flocking.Simulation(model, flocking.State.aligned(model), backend="reference")
    >>> sim.writers.append(flocking.GSDWriter(path, every=5))
    >>> sim.run(20)
    >>> ps = PerSpecies(PolarOrder()).compute(path)
    >>> ps.names, ps["calm"].n, bool(ps["calm"].mean > 0.9), bool(ps["wild"].series[-1] < 0.4)
    (('calm', 'wild'), 100, True, True)
    """

    _keys = ("names", "window_start", "window_rule")

    def __init__(self, quantity=None):
        quantity = PolarOrder() if quantity is None else quantity
        if not isinstance(quantity, _Order) or quantity.species is not None:
            raise ParameterError(f"quantity: must be a PolarOrder() or NematicOrder() of every species "
                                 f"(got {quantity!r})")
        self.quantity = quantity

    def parameters(self) -> dict:
        return {"quantity": type(self.quantity).__name__, "start": self.quantity.start, "dt": self.quantity.dt}

    names = result("names", "The species, in the run's order.")
    orders = result("orders", "The computed quantity of each species, by name.")
    window_start = result("window_start", "First step of the window (common to every species).")
    window_rule = result("window_rule", "How the window was chosen (with start='auto': in the whole flock's series).")
    steps = result("steps", "Step of each value of the series.")
    times = result("times", "Time of each value.")
    window = result("window", "Boolean mask of the values in the window.")

    def __getitem__(self, name: str):
        return self.orders[name]

    def compute(self, system) -> PerSpecies:
        names = species_names(system)
        if len(names) < 2:
            raise ParameterError(f"system: holds {'one species' if names else 'no particle types'}; per-species "
                                 f"quantities need two or more")
        kind, q = type(self.quantity), self.quantity
        start, rule = q.start, None
        if start == "auto":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                whole = kind(start="auto", dt=q.dt).compute(system)
            start, rule = whole.window_start, whole.window_rule
        orders = {}
        for name in names:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                orders[name] = kind(start=start, dt=q.dt, species=name).compute(system)
            for w in caught:
                warnings.warn(str(w.message), w.category, stacklevel=2)
        first = orders[names[0]]
        self._store(names=tuple(names), orders=orders, window_start=first.window_start,
                    window_rule=rule or first.window_rule, steps=first.steps, times=first.times, window=first.window)
        return self

    def to_dict(self) -> dict:
        out = super().to_dict()
        out["species"] = {name: order.to_dict() for name, order in self.orders.items()}
        return out

    def plot(self, ax=None, theme=None):
        """Each species' series against time with its mean and error; the window shaded."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        w = self.times[self.window]
        style.shade_window(ax, w[0], w[-1], theme, label=f"window ({self.window_rule})")
        for i, name in enumerate(self.names):
            order = self.orders[name]
            colour = colours[i % (len(colours) - 1)]
            symbol = order._symbol_of()
            ax.plot(self.times, order.series, lw=0.8, color=colour, alpha=0.85,
                    label=rf"$\langle {symbol}\rangle = {format_value(order.mean, order.mean_error)}$")
            ax.plot(w[[0, -1]], [order.mean, order.mean], color=colour, lw=1.4, ls="--")
        style.label_axes(ax, "time", self.quantity._axis_label)
        legend(ax, theme)
        return ax
