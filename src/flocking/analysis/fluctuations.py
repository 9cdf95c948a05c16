"""Number fluctuations: ``dn`` against ``<n>`` in square (cubic) sub-boxes, and ``alpha``.

For each sub-box side ``l`` the box is cut into ``floor(L_a / l)`` boxes along each axis,
starting at the corner (all of it when ``l`` divides ``L``: the default sizes are
``L_min / m`` for whole ``m``); ``<n>`` and ``dn`` are the mean and standard deviation of
the counts over all sub-boxes of all frames. ``alpha`` is the slope of ``log dn``
against ``log <n>`` (weighted least squares, each ``dn`` weighted by its own sampling
error). Its error is the larger of the fit's formal error (scaled by the scatter) and a
jackknife over frames (when there are at least four). Default sizes stop at ``m = 8``
(at most 1/64 of the box in 2D), so that the fixed total count barely bends the curve.

Walls and obstacles: sub-boxes tile the box from its corner and never wrap, so none spans
a wall or a periodic side. A sub-box that overlaps an obstacle (or a periodic image of
one) is left out, so every count is of the same free area and the counts of a
homogeneous state share one mean; ``notes`` says how many were kept.

>>> import numpy as np
>>> rng = np.random.default_rng(2)
>>> frames = [(100.0, rng.uniform(0, 100, (20000, 2))) for _ in range(4)]
>>> nf = NumberFluctuations().compute(frames)
>>> bool(abs(nf.alpha - 0.5) < 4 * nf.alpha_error < 0.1)
True
"""

from __future__ import annotations

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import snapshots
from .base import Analysis, fit_line, format_value, legend, log_ticks, result
from .fieldinput import FieldCounts, is_fields


def default_sizes(box: np.ndarray, n: int, count: int = 24) -> np.ndarray:
    """Sides ``L_min / m``: whole ``m`` log-spaced from 8 up to one particle per sub-box."""
    dim = len(box)
    m_max = max(int((n * np.min(box) ** dim / np.prod(box)) ** (1.0 / dim)), 8)
    ms = np.unique(np.round(np.geomspace(8, m_max, count)).astype(int))
    return np.min(box) / ms[::-1].astype(float)


class SubBoxes:
    """The whole sub-boxes of side ``side`` in ``space`` (``shape`` per axis, or ``None``
    when the side exceeds the box), and which of them no obstacle touches (``keep``)."""

    def __init__(self, space: Space, side: float):
        self.side = side
        cells = np.floor(space.lengths / side * (1 + 1e-12)).astype(np.int64)
        self.shape = tuple(cells) if np.all(cells >= 1) else None
        self.keep = None
        if self.shape is not None:
            self.keep = np.ones(int(np.prod(cells)), bool)
            if space.obstacles:
                corners = np.indices(self.shape).reshape(space.dim, -1).T * side
                self.keep = ~space.boxes_touch_obstacle(corners, side)

    def moments(self, positions: np.ndarray) -> np.ndarray:
        """Sums of ``n^k`` (k = 0..4) over the kept sub-boxes."""
        idx = np.floor(positions / self.side).astype(np.int64)
        inside = np.all(idx < self.shape, axis=1)
        flat = np.ravel_multi_index(tuple(idx[inside].T), self.shape)
        counts = np.bincount(flat, minlength=len(self.keep))[self.keep].astype(float)
        return np.array([counts.size, counts.sum(), (counts**2).sum(), (counts**3).sum(), (counts**4).sum()])


def _stats(m):
    """``(mean, dn, error of log dn)`` from pooled sums of powers (NaN without a box)."""
    k, s1, s2, s3, s4 = m
    if k == 0:
        return np.nan, np.nan, np.inf
    mean = s1 / k
    var = max(s2 / k - mean * mean, 0.0)
    mu4 = s4 / k - 4 * mean * s3 / k + 6 * mean**2 * s2 / k - 3 * mean**4
    sigma = 0.5 * np.sqrt(max(mu4 - var * var, 0.0) / k) / var if var > 0 else np.inf
    return mean, np.sqrt(var * k / max(k - 1, 1)), sigma


def fluctuation_notes(space: Space, boxes, fitted, alpha: float) -> list[str]:
    """The sub-boxes that obstacles left out, and why ``alpha`` is NaN."""
    notes = []
    if space.obstacles:
        big, small = max(boxes, key=lambda b: b.side), min(boxes, key=lambda b: b.side)
        notes.append(f"sub-boxes that overlap an obstacle are left out: kept {big.keep.sum()} of {len(big.keep)} "
                     f"at the largest side {big.side:.4g}, {small.keep.sum()} of {len(small.keep)} at the smallest "
                     f"{small.side:.4g}")
        lost = [f"{b.side:.4g}" for b in boxes if not b.keep.any()]
        if lost:
            notes.append(f"sides {', '.join(lost)}: every sub-box overlaps an obstacle, so they give no count")
    if np.isnan(alpha):
        notes.append(f"alpha: NaN, {int(fitted.sum())} size{'s' * int(fitted.sum() != 1)} with counts that "
                     "fluctuate in the fit range (a slope needs two); give other sizes or fit_range")
    return notes


class NumberFluctuations(Analysis):
    """Giant number fluctuations: ``dn ~ <n>^alpha``.

    Parameters
    ----------
    sizes
        Sub-box sides (default: see the module); a side larger than the box is refused.
    fit_range
        ``(n_min, n_max)``: fit only sizes whose ``<n>`` lies in it (default: all).
    start, frames
        The window (see :func:`flocking.analysis.snapshots.select`).
    """

    _keys = ("sizes", "mean", "std", "alpha", "alpha_error", "fitted", "num_frames")

    def __init__(self, sizes=None, fit_range=None, start=None, frames=None):
        if sizes is not None:
            sizes = np.atleast_1d(np.asarray(sizes, dtype=float))
            if sizes.ndim != 1 or sizes.size == 0 or not np.all(np.isfinite(sizes)) or np.any(sizes <= 0):
                raise ParameterError(f"sizes: must be positive sub-box sides (got {sizes.tolist()})")
        if fit_range is not None:
            if len(fit_range) != 2 or not 0 <= fit_range[0] < fit_range[1]:
                raise ParameterError(f"fit_range: must be (n_min, n_max) with 0 <= n_min < n_max (got {fit_range!r})")
        snapshots.window_start(start, [0], 1)
        self.sizes_requested, self.fit_range = sizes, fit_range
        self.start, self.frames = start, snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"sizes": self.sizes_requested, "fit_range": self.fit_range, "start": self.start,
                "frames": self.frames}

    sizes = result("sizes", "Sub-box sides l.")
    mean = result("mean", "<n> per size.")
    std = result("std", "dn (standard deviation of the count) per size.")
    log_error = result("log_error", "Sampling error of log dn per size.")
    fitted = result("fitted", "Boolean mask of the sizes used in the fit.")
    alpha = result("alpha", "Exponent of dn ~ <n>^alpha.")
    alpha_error = result("alpha_error", "Uncertainty of alpha.")
    intercept = result("intercept", "log dn = alpha log <n> + intercept.")
    num_frames = result("num_frames", "Number of frames averaged.")

    def compute(self, system) -> NumberFluctuations:
        """``system``: frames of particles, or coarse-grained fields (a fields file or
        dataset, :mod:`flocking.fields`), whose sub-boxes are then whole bins."""
        if is_fields(system):
            space, sizes, boxes, per_frame = self._from_fields(FieldCounts(system).window(self.start, self.frames))
        else:
            space, sizes, boxes, per_frame = self._from_frames(system)
        stats = np.array([_stats(m) for m in per_frame.sum(axis=0)])
        mean, std, sigma = stats.T
        fitted = (std > 0) & np.isfinite(sigma) & (mean > 0)
        if self.fit_range is not None:
            fitted &= (mean >= self.fit_range[0]) & (mean <= self.fit_range[1])
        alpha, intercept, error = self._fit(mean, std, sigma, fitted)
        nf = len(per_frame)
        if nf >= 4 and fitted.sum() >= 2:
            groups = np.array_split(np.arange(nf), min(nf, 20))
            total = per_frame.sum(axis=0)
            slopes = []
            for g in groups:
                s = np.array([_stats(m) for m in total - per_frame[g].sum(axis=0)])
                ok = fitted & (s[:, 1] > 0) & np.isfinite(s[:, 2])
                slopes.append(self._fit(s[:, 0], s[:, 1], s[:, 2], ok)[0])
            slopes = np.array(slopes)
            g = len(groups)
            error = max(error, float(np.sqrt((g - 1) / g * np.sum((slopes - slopes.mean()) ** 2))))
        notes = fluctuation_notes(space, boxes, fitted, alpha)
        self._store(sizes=np.asarray(sizes, float), mean=mean, std=std, log_error=sigma, fitted=fitted,
                    alpha=alpha, alpha_error=error, intercept=intercept, num_frames=nf, notes=notes)
        return self

    def _from_frames(self, system):
        """``(space, sizes, boxes, moments (frames, sizes, 5))`` of particle frames."""
        frames = snapshots.select(snapshots.as_frames(system), self.start, self.frames)
        first = frames[0]
        sizes = self.sizes_requested if self.sizes_requested is not None else default_sizes(first.box, first.n)
        boxes = self._boxes(first.space, sizes)
        per_frame = []
        for f in frames:
            if f.dim != first.dim or np.any(f.box != first.box):
                raise ParameterError("system: every frame must have the same box")
            per_frame.append(np.array([b.moments(f.positions) for b in boxes]))
        return first.space, sizes, boxes, np.array(per_frame)

    def _from_fields(self, fields: FieldCounts):
        """The same from the counts of a fields file: sub-boxes of ``k x k`` bins (default
        ``k`` log-spaced from 1 to an eighth of the grid's shortest side)."""
        sizes = self.sizes_requested
        if sizes is None:
            widest = max(1, min(fields.counts.shape[1:]) // 8)
            ks = np.unique(np.round(np.geomspace(1, widest, 24)).astype(int))
            sizes = ks * float(np.min(fields.widths))
        boxes = self._boxes(fields.space, sizes)
        per_frame = np.zeros((len(fields.counts), len(sizes), 5))
        for j, (side, b) in enumerate(zip(sizes, boxes)):
            counts = fields.block_counts(fields.bins_per_side(side))[:, b.keep]
            per_frame[:, j] = np.stack([np.full(len(counts), counts.shape[1])]
                                       + [(counts**p).sum(axis=1) for p in range(1, 5)], axis=1)
        return fields.space, sizes, boxes, per_frame

    @staticmethod
    def _boxes(space, sizes) -> list[SubBoxes]:
        boxes = [SubBoxes(space, s) for s in sizes]
        if any(b.shape is None for b in boxes):
            raise ParameterError(f"sizes: every side must fit in the box {list(space.lengths)} "
                                 f"(got {np.asarray(sizes).tolist()})")
        return boxes

    @staticmethod
    def _fit(mean, std, sigma, mask):
        if mask.sum() < 2:
            return float("nan"), float("nan"), float("nan")
        return fit_line(np.log(mean[mask]), np.log(std[mask]), sigma[mask])

    def plot(self, ax=None, theme=None):
        """``dn`` against ``<n>`` on log-log axes with the fitted power law (over the fitted
        sizes, filled markers) and the ideal gas' ``<n>^(1/2)`` for reference."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        if not self.fitted.all():
            ax.loglog(self.mean[~self.fitted], self.std[~self.fitted], "o", ms=3.5, mfc="none", color=colours[0],
                      label="measured, left out of the fit")
        ax.loglog(self.mean[self.fitted], self.std[self.fitted], "o", ms=3.5, color=colours[0],
                  label="measured" + (", fitted" if not self.fitted.all() else ""))
        x = self.mean[self.fitted]
        if len(x) >= 2:
            ax.loglog(x, np.exp(self.intercept) * x**self.alpha, "-", color=colours[1], lw=1.2,
                      label=rf"$\alpha = {format_value(self.alpha, self.alpha_error)}$")
        ref = self.mean[0]
        ax.loglog(self.mean, np.sqrt(self.mean / ref) * self.std[0], ":", color=colours[-1], lw=1,
                  label=r"$\propto\langle n\rangle^{1/2}$")
        style.label_axes(ax, "mean_count", "count_std")
        log_ticks(ax)
        legend(ax, theme)
        return ax
