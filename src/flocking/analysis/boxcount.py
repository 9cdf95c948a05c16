"""Box-counting (Minkowski) dimension of a set of points or of a 2D/3D image.

Boxes of side ``eps = L / 2^k`` (points: ``L`` the smallest box side, or the bounding
cube's side when no box is known) or of ``2^k`` pixels (a boolean image); ``N(eps)`` is
the number of boxes holding at least one point or pixel, and the dimension is the
slope of ``log N`` against ``log(1 / eps)`` over the fit range. The default range for
points starts at ``eps = L/2`` and stops before the boxes get so small that ``N(eps)``
exceeds a tenth of the number of points (there the count saturates: for uniform points,
``lambda`` per box on average, the local slope is ``d (1 - lambda e^-lambda / (1 -
e^-lambda))``, 0.05 % low at ``lambda = 10``, 3.4 % at 5); for an image it runs from one pixel
to half the image. The error is the fit's standard error (0 for an exact power law); a fit
through two sizes has no degree of freedom left and so no error (NaN), and a default range
that holds only two sizes (too few points for their dimension, such as 1000 points in 3D)
raises a ``RuntimeWarning``.

Walls change nothing: the boxes tile the box from its corner, and none spans a side.
Obstacles are counted as box, empty: ``notes`` says what share of the box they cover
(at sides well below an obstacle's size ``N(eps)`` drops by that share, a constant factor
that leaves the slope as it is; at sides comparable to it the curve bends).

>>> import numpy as np
>>> i, j = np.indices((64, 64))
>>> sierpinski = (i & j) == 0                 # Pascal's triangle mod 2
>>> bc = BoxCounting().compute(sierpinski)
>>> bool(np.isclose(bc.dimension, np.log(3) / np.log(2))), bc.dimension_error
(True, 0.0)
"""

from __future__ import annotations

import warnings

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import snapshots
from .base import Analysis, fit_line, format_value, legend, log_ticks, result


def image_counts(image: np.ndarray):
    """``(sides in pixels, occupied boxes)`` for sides 1, 2, 4, ... up to the image size."""
    img = np.asarray(image, dtype=bool)
    sides, counts = [], []
    side = 1
    while True:
        sides.append(side)
        counts.append(int(img.sum()))
        if max(img.shape) == 1:
            break
        pad = [(0, s % 2) for s in img.shape]
        img = np.pad(img, pad)
        for a in range(img.ndim):
            img = img.reshape(img.shape[:a] + (img.shape[a] // 2, 2) + img.shape[a + 1:]).any(axis=a + 1)
        side *= 2
    return np.array(sides, float), np.array(counts)


def point_counts(points: np.ndarray, origin, length: float, levels: int):
    """``(eps, occupied boxes)`` for ``eps = length / 2^k``, ``k = 0..levels``, coarse to
    fine, stopping early once the count reaches half the number of points (saturation)."""
    n, dim = points.shape
    scaled = np.clip((points - origin) / length, 0, None)
    extent = np.ceil(scaled.max(axis=0) + 1e-12)  # boxes of side ``length`` per axis
    counts = []
    for k in range(levels + 1):
        per_axis = (extent * 2**k).astype(np.int64)
        idx = np.minimum(np.floor(scaled * 2.0**k).astype(np.int64), per_axis - 1)
        key = np.ravel_multi_index(tuple(idx.T), tuple(per_axis)) if np.prod(per_axis.astype(float)) < 2**62 \
            else None
        if key is None:
            break
        if np.prod(per_axis.astype(float)) <= 8 * n:
            occupied = np.zeros(int(np.prod(per_axis)), bool)
            occupied[key] = True  # O(N), no sort
            counts.append(int(occupied.sum()))
        else:
            counts.append(len(np.unique(key)))
        if counts[-1] >= n / 2:
            break
    counts = np.array(counts)
    return length / 2.0 ** np.arange(len(counts)), counts


def obstacle_note(space: Space) -> str:
    """What box counting does with the obstacles of ``space``."""
    share = float(space.in_obstacle(space.grid()).mean())
    return (f"obstacles cover {share:.1%} of the box and are counted as box: the boxes inside them stay empty, "
            "which lowers N(eps) by that share at sides well below their size (the slope holds) and bends it at "
            "sides comparable to it")


class BoxCounting(Analysis):
    """Box-counting dimension.

    Parameters
    ----------
    fit_range
        ``(eps_min, eps_max)`` in length units (pixels for an image): fit only box
        sides in it. Default: see the module.
    start
        For a trajectory, the window; the last frame of it is measured.

    Notes
    -----
    ``compute(system, box=None)``: ``system`` is a boolean image (2D or 3D array), an
    ``(N, d)`` array of points (in ``box``, a number or one length per axis, or in their
    bounding cube), or anything with frames (positions in the periodic box).
    """

    _keys = ("scales", "counts", "fitted", "dimension", "dimension_error", "fit_range_used")

    def __init__(self, fit_range=None, start=None):
        if fit_range is not None and (len(fit_range) != 2 or not 0 < fit_range[0] < fit_range[1]):
            raise ParameterError(f"fit_range: must be (eps_min, eps_max) with 0 < eps_min < eps_max "
                                 f"(got {fit_range!r})")
        snapshots.window_start(start, [0], 1)
        self.fit_range, self.start = fit_range, start

    def parameters(self) -> dict:
        return {"fit_range": self.fit_range, "start": self.start}

    scales = result("scales", "Box sides eps, largest first.")
    counts = result("counts", "Occupied boxes N(eps).")
    fitted = result("fitted", "Boolean mask of the scales in the fit.")
    dimension = result("dimension", "Box-counting dimension.")
    dimension_error = result("dimension_error", "Standard error of the fitted slope (NaN from two sizes).")
    intercept = result("intercept", "log N = dimension log(1/eps) + intercept.")
    fit_range_used = result("fit_range_used", "(eps_min, eps_max) of the fitted scales.")

    def compute(self, system, box=None) -> BoxCounting:
        arr = system if isinstance(system, np.ndarray) else None
        notes = []
        if arr is not None and arr.dtype == bool:
            if arr.ndim not in (2, 3) or not arr.any():
                raise ParameterError(f"image: must be a 2D or 3D boolean array with some True pixel "
                                     f"(got shape {arr.shape})")
            scales, counts = image_counts(arr)
            default = (scales >= 1) & (scales <= max(min(arr.shape) / 2, 1))
        else:
            if arr is not None:
                points = np.asarray(arr, dtype=float)
                if points.ndim != 2 or points.shape[1] not in (1, 2, 3) or len(points) == 0 \
                        or not np.all(np.isfinite(points)):
                    raise ParameterError(f"points: must be a non-empty finite (N, d) array, d <= 3 "
                                         f"(got shape {points.shape})")
                if box is None:
                    origin = points.min(axis=0)
                    length = float(np.max(points.max(axis=0) - origin)) * (1 + 1e-9)
                    length = length if length > 0 else 1.0
                else:
                    lengths = np.broadcast_to(np.asarray(box, float), (points.shape[1],))
                    if np.any(lengths <= 0):
                        raise ParameterError(f"box: side lengths must be positive (got {box!r})")
                    points = Space(tuple(lengths)).inside(points)
                    origin, length = np.zeros(points.shape[1]), float(lengths.min())
            else:
                frame = snapshots.select(snapshots.as_frames(system), self.start)[-1]
                points, origin, length = frame.positions, np.zeros(frame.dim), float(frame.box.min())
                if frame.space.obstacles:
                    notes.append(obstacle_note(frame.space))
            n = len(points)
            levels = int(min(max(np.ceil(np.log2(max(n, 2)) / points.shape[1]) + 8, 4), 60 // points.shape[1] - 2))
            scales, counts = point_counts(points, origin, length, levels)
            default = (scales <= length / 2) & (counts <= max(n / 10, 1))
            if default.sum() < 2:  # few points: go as far as half saturation
                default = (scales <= length / 2) & (counts <= n / 2)
        fitted = default
        if self.fit_range is not None:
            eps_min, eps_max = self.fit_range
            fitted = (scales >= eps_min * (1 - 1e-9)) & (scales <= eps_max * (1 + 1e-9))
        if fitted.sum() < 2:
            raise ParameterError(f"fit_range: fewer than two box sizes to fit (sizes available: "
                                 f"{scales.tolist()})")
        if self.fit_range is None and fitted.sum() == 2:
            warnings.warn(f"BoxCounting: the default fit range holds only two box sizes ({scales[fitted].max():.4g} "
                          f"and {scales[fitted].min():.4g}) before the count saturates, so the dimension has no "
                          "error estimate; use more points, or give fit_range", RuntimeWarning, stacklevel=2)
        slope, intercept, err = fit_line(np.log(1 / scales[fitted]), np.log(counts[fitted]))
        if np.isnan(err):
            notes.append("dimension_error: NaN, the fit goes through two box sizes only, which leave no degree of "
                         "freedom to estimate it")
        self._store(scales=scales, counts=counts, fitted=fitted, dimension=slope, dimension_error=err,
                    intercept=intercept, fit_range_used=(float(scales[fitted].min()), float(scales[fitted].max())),
                    notes=notes)
        return self

    def plot(self, ax=None, theme=None):
        """``N(eps)`` against ``eps``, log-log, with the fitted line over the fitted sizes
        (filled markers)."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        if not self.fitted.all():
            ax.loglog(self.scales[~self.fitted], self.counts[~self.fitted], "o", ms=4, mfc="none", color=colours[0],
                      label="not fitted")
        ax.loglog(self.scales[self.fitted], self.counts[self.fitted], "o", ms=4, color=colours[0], label="fitted")
        x = self.scales[self.fitted]
        ax.loglog(x, np.exp(self.intercept) * x ** -self.dimension, "-", color=colours[1], lw=1.2,
                  label=f"$D = {format_value(self.dimension, self.dimension_error)}$")
        style.label_axes(ax, "box_size", "boxes")
        log_ticks(ax)
        legend(ax, theme)
        return ax
