"""2D frames as density maps, drawn with NumPy into RGB arrays at any particle count.

Particles are binned on a grid of about one bin a pixel and smoothed with a Gaussian,
periodic along periodic axes and cut at walls, wide enough to hold a set number of
particles (and at most 1/32 of the picture), so the map shows structure, not counting
noise. Where walls or obstacles take part of a kernel's area, the density is divided by
the free part, so a crowd along a wall or around an obstacle keeps its true density.

* brightness is the local number density (particles per unit area), on a fixed scale
  that a colour bar can show (:func:`density_scale`); coloured by species, the hue
  mixes the species' colours in their local proportions;
* hue is the local mean heading and chroma the local polar order, estimated over a
  wider kernel and corrected for the order that random headings show by chance
  (``|sum of n random unit vectors|^2`` is ``n`` on average). Colour shows only where
  the local order is significant: where ``|S|^2`` exceeds its mean for random headings
  by a factor :data:`SIGNIFICANT` or more (random headings do so with probability
  ``exp(-SIGNIFICANT)``), fading in from half that factor. Too few particles are never
  significant, so a disordered gas is grey and bands and ordered clusters stand out.

Images are ``float`` RGB in [0, 1], rows top to bottom (image order).

>>> from flocking.viz.colors import THEMES
>>> rng = np.random.default_rng(0)
>>> pos = rng.uniform(-8, 8, (4000, 2))
>>> ordered = DensityField(pos, np.tile([1.0, 0.0], (4000, 1)), (16.0, 16.0), (64, 64))
>>> random = DensityField(pos, rng.normal(size=(4000, 2)), (16.0, 16.0), (64, 64))
>>> round(float(ordered.density.mean()), 3), round(float(ordered.order.mean()), 2), float(random.order.mean()) < 0.1
(15.625, 1.0, True)
>>> density_image(ordered, THEMES["dark"], vmax=32.0).shape
(64, 64, 3)
"""

from __future__ import annotations

import math

import numpy as np

from ..space import Space
from .colors import Theme, angle_colors

#: The density kernel holds this many particles on average (relative noise 1/5).
DENSITY_COUNT = 25.0
#: The order kernel holds this many particles on average.
ORDER_COUNT = 40.0
#: Colour shows in full where ``|S|^2`` is this many times its mean for random headings.
SIGNIFICANT = 10.0
#: Brightness is ``(density / vmax) ** GAMMA``: sparse regions stay visible.
GAMMA = 0.5


def grid_shape(box_lengths, max_pixels: int) -> tuple[int, int]:
    """``(rows, columns)`` of the density grid: square bins, the longer side ``max_pixels``."""
    lx, ly = float(box_lengths[0]), float(box_lengths[1])
    longest = max(16, int(max_pixels))
    if lx >= ly:
        return max(8, round(longest * ly / lx)), longest
    return longest, max(8, round(longest * lx / ly))


def _kernel_ft(shape, sigma: float, square: bool = False) -> np.ndarray:
    """Fourier transform (``rfft2`` layout) of a periodic Gaussian of ``sigma`` bins whose
    weights sum to 1 (``square``: the same weights squared, which sum to less)."""
    factors = []
    for axis, size in enumerate(shape):
        offset = np.minimum(np.arange(size), size - np.arange(size))  # periodic distance in bins
        g = np.exp(-0.5 * (offset / max(sigma, 1e-9)) ** 2)
        g /= g.sum()
        if square:
            g = g * g
        ft = np.fft.rfft(g) if axis == 1 else np.fft.fft(g)
        factors.append(ft)
    return factors[0][:, None] * factors[1][None, :]


def _smooth(grid: np.ndarray, kernel_ft: np.ndarray) -> np.ndarray:
    return np.fft.irfft2(np.fft.rfft2(grid) * kernel_ft, s=grid.shape)


class _Smoother:
    """Gaussian smoothing of grids of ``shape``: periodic, except along wall axes
    (``walls`` as (x, y)), where the grid is padded with as many empty bins, so that
    nothing wraps around from the other wall."""

    def __init__(self, shape, walls):
        self.shape = tuple(shape)
        self.padded = tuple(2 * n if wall else n for n, wall in zip(self.shape, walls[::-1]))  # (rows: y, cols: x)
        self._kernels = {}

    def __call__(self, grid: np.ndarray, sigma: float, square: bool = False) -> np.ndarray:
        key = (sigma, square)
        if key not in self._kernels:
            self._kernels[key] = _kernel_ft(self.padded, sigma, square)
        if self.padded != self.shape:
            big = np.zeros(self.padded)
            big[: self.shape[0], : self.shape[1]] = grid
            return _smooth(big, self._kernels[key])[: self.shape[0], : self.shape[1]]
        return _smooth(grid, self._kernels[key])


class DensityField:
    """Smoothed density, local order and mean heading of a 2D frame on a grid.

    ``positions`` are centred in the box; ``shape`` is ``(rows, columns)``; rows run
    downward (+y up). ``walls`` (per axis) cut the smoothing; ``obstacles`` (rows ``cx,
    cy, r`` in centred coordinates, with their periodic images) are no free space;
    ``typeid`` (and ``types``, their number) sort particles into species. Attributes,
    each of ``shape``: ``density`` (particles per unit area of free space), ``order``
    (local polar order in [0, 1], 0 where too few particles), ``angle`` (direction of the
    local mean heading, radians), ``count`` (effective number of particles in the order
    kernel), ``significance`` (``|S|^2`` over its mean for random headings),
    ``free`` (whether a bin is outside the obstacles); ``fractions``, ``(types, rows,
    columns)``: each species' share of the density.
    """

    def __init__(self, positions, headings, box_lengths, shape, walls=(False, False), obstacles=None,
                 typeid=None, types=1):
        ny, nx = shape
        lx, ly = float(box_lengths[0]), float(box_lengths[1])
        positions = np.asarray(positions, float)
        headings = np.asarray(headings, float)
        ix = np.clip(((positions[:, 0] / lx + 0.5) * nx).astype(np.int64), 0, nx - 1)
        iy = np.clip(((0.5 - positions[:, 1] / ly) * ny).astype(np.int64), 0, ny - 1)  # rows downward
        cell = iy * nx + ix
        count = np.bincount(cell, minlength=nx * ny).astype(float).reshape(ny, nx)
        sx = np.bincount(cell, weights=headings[:, 0], minlength=nx * ny).reshape(ny, nx)
        sy = np.bincount(cell, weights=headings[:, 1], minlength=nx * ny).reshape(ny, nx)
        self.free = _free_mask(np.zeros((0, 3)) if obstacles is None else obstacles, (lx, ly), shape)
        per_bin = max(len(positions), 1) / max(int(self.free.sum()), 1)
        widest = max(shape) / 32  # sparse frames stay noisy rather than become a haze
        self.sigma_density = min(self.kernel_width(DENSITY_COUNT, per_bin), widest)
        self.sigma_order = min(self.kernel_width(ORDER_COUNT, per_bin), widest)
        bin_area = (lx / nx) * (ly / ny)
        smooth = _Smoother(shape, tuple(walls)[:2])
        # the share of each kernel that is free space: 1 but beside walls and obstacles
        area = 1.0
        if any(walls) or not self.free.all():
            area = np.maximum(smooth(self.free.astype(float), self.sigma_density), 1e-3)
        self.density = np.where(self.free, np.maximum(smooth(count, self.sigma_density), 0.0) / area, 0.0) / bin_area
        self.fractions = np.ones((1, ny, nx))
        if typeid is not None and types > 1:
            cells = np.asarray(typeid, np.int64) * (nx * ny) + cell
            per_type = np.bincount(cells, minlength=types * nx * ny).astype(float).reshape(types, ny, nx)
            smoothed = np.maximum(np.stack([smooth(g, self.sigma_density) for g in per_type]), 0.0)
            total = smoothed.sum(axis=0)
            self.fractions = np.divide(smoothed, total, out=np.full_like(smoothed, 1.0 / types), where=total > 1e-9)
        w1 = np.maximum(smooth(count, self.sigma_order), 0.0)
        w2 = np.maximum(smooth(count, self.sigma_order, square=True), 0.0)
        px, py = smooth(sx, self.sigma_order), smooth(sy, self.sigma_order)
        # |S|^2 is W2 on average for random headings and W1^2 for aligned ones; pixels
        # that no particle reaches hold only the rounding noise of the FFT
        reached = (w1 > 1e-9 * w1.max()) & (w2 > 1e-9 * w2.max())
        denominator = w1 * w1 - w2
        ok = reached & (denominator > 1e-12 * w1 * w1)
        ratio = np.divide(px * px + py * py - w2, denominator, out=np.zeros_like(w1), where=ok)
        self.count = np.divide(w1 * w1, w2, out=np.zeros_like(w1), where=reached)
        self.significance = np.divide(px * px + py * py, w2, out=np.zeros_like(w1), where=reached)
        trust = np.clip(2.0 * self.significance / SIGNIFICANT - 1.0, 0.0, 1.0)
        self.order = np.sqrt(np.clip(ratio, 0.0, 1.0)) * trust
        self.angle = np.arctan2(py, px)
        self.mean_density = len(positions) / (lx * ly * self.free.mean())

    @staticmethod
    def kernel_width(particles: float, per_bin: float) -> float:
        """Gaussian width (bins) whose kernel holds ``particles`` on average: a normalised
        Gaussian of width sigma averages over an area of ``4 pi sigma^2``."""
        return max(0.7, math.sqrt(particles / (4 * math.pi * max(per_bin, 1e-12))))


def nice_ceiling(x: float) -> float:
    """The smallest of 1, 1.5, 2, 3, 4, 5, 6, 8 x 10^k that is at least ``x``.

    >>> nice_ceiling(7.2), nice_ceiling(0.31), nice_ceiling(10.0)
    (8.0, 0.4, 10.0)
    """
    if not x > 0:
        return 1.0
    k = math.floor(math.log10(x))
    for m in (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10.0**k >= x * (1 - 1e-12):
            return float(round(m * 10.0**k, 12))
    return 10.0 ** (k + 1)


def density_scale(fields) -> float:
    """Top of the density scale for these fields: a round number above the 99.5th
    percentile of their densities and at least twice the mean density, so that a
    homogeneous state shows as mid-grey and bands and clusters stand out."""
    top = max(max(float(np.percentile(f.density, 99.5)), 2.0 * f.mean_density) for f in fields)
    return nice_ceiling(top)


def density_image(field: DensityField, theme: Theme, vmax: float, species=None) -> np.ndarray:
    """RGB image of a :class:`DensityField`: brightness ``(density / vmax) ** GAMMA``,
    hue the mean heading, chroma the local order; or, given ``species`` colours
    (``(types, 3)`` RGB), the species' colours mixed in their local proportions."""
    alpha = np.clip(field.density / vmax, 0.0, 1.0) ** GAMMA
    if species is not None:
        ink = np.einsum("syx,sc->yxc", field.fractions, np.asarray(species, float)[: len(field.fractions)])
    else:
        ink = angle_colors(field.angle, theme, field.order, ink=True)
    background = np.asarray(theme.background, float)
    return background + alpha[..., None] * (ink - background)


def density_ticks(vmax: float, spacing: float = 0.14) -> list[float]:
    """Round ticks for a density colour bar of top ``vmax``: 1-2-5 numbers and ``vmax``,
    at least ``spacing`` apart on the bar's ``GAMMA`` scale, and 0.

    >>> density_ticks(15.0), density_ticks(4.0)
    ([0.0, 0.5, 2.0, 5.0, 10.0, 15.0], [0.0, 0.1, 0.5, 1.0, 2.0, 4.0])
    """
    k = math.floor(math.log10(vmax))
    candidates = [m * 10.0**e for e in range(k - 3, k + 1) for m in (1.0, 2.0, 5.0) if m * 10.0**e < vmax]
    ticks, last = [vmax], 1.0
    for value in sorted(candidates, reverse=True):
        position = (value / vmax) ** GAMMA
        if last - position >= spacing and position >= spacing:
            ticks.append(float(round(value, 12)))
            last = position
    return [0.0] + sorted(ticks)


def density_colormap(theme: Theme):
    """The colour map of zero-order ink over the background, for the density colour bar."""
    from matplotlib.colors import LinearSegmentedColormap

    grey = angle_colors(0.0, theme, 0.0, ink=True)
    return LinearSegmentedColormap.from_list(f"density-{theme.name}", [theme.background, tuple(grey)])


def _free_mask(obstacles: np.ndarray, box_lengths, shape) -> np.ndarray:
    """``shape = (rows, columns)`` booleans of a 2D grid (rows downward): whether each
    bin's centre lies outside every obstacle (``obstacles`` already with their images, so
    no further image is taken: :meth:`flocking.space.Space.in_obstacle` with walls)."""
    ny, nx = shape
    lx, ly = float(box_lengths[0]), float(box_lengths[1])
    x = ((np.arange(nx) + 0.5) / nx - 0.5) * lx
    y = (0.5 - (np.arange(ny) + 0.5) / ny) * ly
    centres = np.stack(np.broadcast_arrays(x[None, :], y[:, None]), axis=-1)
    space = Space((lx, ly), (True, True), np.asarray(obstacles, float).reshape(-1, 3), (-lx / 2, -ly / 2))
    return ~space.in_obstacle(centres)
