"""Connected velocity correlation ``C(r)`` (docs/model.md) and the correlation length.

``C(r) = sum_{i != j} du_i . du_j [r_ij in bin] / sum_{i != j} [r_ij in bin]`` with
``du_i = u_i - mean(u)``, summed over the frames before the ratio. Distances are the
engine's (:class:`flocking.space.Space`): the minimum image along periodic axes, the
plain difference between walls, so no pair reaches across a wall; obstacles hide no
neighbour in the engine, so pairs across them count. Two methods:

- ``"cells"``: exact, the pairs of :meth:`flocking.space.Space.pair_histogram` (a cell
  list with cells of side ``>= r_max``): O(N) per frame for a fixed ``r_max`` (the cost grows
  as ``N rho r_max^d``).
- ``"grid"``: the headings are summed on a grid of spacing ``dr / 2`` and the pair sums
  come from one FFT autocorrelation, O(M log M) for M grid cells, for any ``r_max``;
  along axes with walls the grid is padded with as many empty cells, so that the FFT's
  correlation does not wrap around (exact: no pair across a wall). A pair's distance is
  that of its grid cells (off by at most a cell diagonal), and pairs that share a cell
  count at distance 0.
- ``"auto"`` (default): cells when that means fewer than about 3e8 distance
  evaluations, the grid otherwise.

Both satisfy the sum rule exactly: with ``r_max`` at least the box diagonal (half of it
along periodic axes), ``sum_bins pairs(r) C(r) = -sum_i |du_i|^2``. The correlation
length is the first zero of ``C`` (linear interpolation between bin centres); NaN when
``C`` stays positive up to ``r_max``, which ``notes`` then says.

>>> import numpy as np
>>> rng = np.random.default_rng(3)
>>> pts, u = rng.uniform(0, 8, (300, 2)), rng.normal(size=(300, 2))
>>> vc = VelocityCorrelation(r_max=6.0, dr=0.5).compute((8.0, pts, u))
>>> du = vc.du_squared
>>> bool(np.isclose((vc.correlation * vc.pairs).sum(), -du))
True
"""

from __future__ import annotations

import math

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import snapshots
from .base import Analysis, legend, pair_notes, positive, result

METHODS = ("auto", "cells", "grid")


def first_zero(r: np.ndarray, c: np.ndarray) -> float:
    """Where ``c`` first crosses zero from above (linear interpolation); NaN if never."""
    ok = np.isfinite(c)
    r, c = r[ok], c[ok]
    if len(c) == 0:
        return float("nan")
    if c[0] <= 0:
        return float(r[0])
    below = np.nonzero(c <= 0)[0]
    if len(below) == 0:
        return float("nan")
    b = below[0]
    return float(r[b - 1] + (r[b] - r[b - 1]) * c[b - 1] / (c[b - 1] - c[b]))


def cell_sums(space: Space, positions, du, r_max: float, nbins: int):
    """``(sum of du_i.du_j, number of ordered pairs i != j)`` per bin of ``[0, r_max)``,
    over the pairs closer than ``r_max`` in ``space``."""
    counts, sums = space.pair_histogram(positions, r_max, nbins, du)
    return 2.0 * sums, 2.0 * counts  # (i, j) and (j, i)


def grid_sums(space: Space, positions, du, r_max: float, dr: float, max_cells: int = 1 << 24):
    """Pair sums and counts per bin from an FFT autocorrelation on a grid, padded along
    axes with walls so that the correlation does not wrap across them."""
    box = space.lengths
    dim = len(box)
    spacing = dr / 2
    shape = np.maximum(np.round(box / spacing), 1).astype(np.int64)
    padding = np.where(space.walls, 2, 1)
    while np.prod(shape * padding) > max_cells:
        shape = np.maximum(shape // 2, 1)
    h = box / shape
    idx = np.minimum((positions / h).astype(np.int64), shape - 1)
    padded = tuple(shape * padding)
    flat = np.ravel_multi_index(tuple(idx.T), padded)
    size = int(np.prod(padded))

    def auto(weights):
        field = np.bincount(flat, weights=weights, minlength=size).reshape(padded)
        f = np.fft.rfftn(field)
        return np.fft.irfftn(f * np.conj(f), s=padded, axes=tuple(range(dim)))

    products = sum(auto(du[:, a]) for a in range(du.shape[1]))
    counts = auto(None)
    products.flat[0] -= float((du * du).sum())  # remove i = j
    counts.flat[0] -= len(positions)
    dist2 = np.zeros(padded)
    for a in range(dim):
        k = np.arange(padded[a])
        d = np.minimum(k, padded[a] - k) * h[a]  # a lag of k cells, or of k - padded (negative)
        dist2 = dist2 + (d**2).reshape([-1 if b == a else 1 for b in range(dim)])
    r = np.sqrt(dist2).ravel()
    nbins = int(round(r_max / dr))
    inside = r < r_max
    b = np.minimum((r[inside] / dr).astype(np.int64), nbins - 1)
    return (np.bincount(b, weights=products.ravel()[inside], minlength=nbins),
            np.rint(np.bincount(b, weights=counts.ravel()[inside], minlength=nbins)))


def reach(space: Space) -> float:
    """The largest distance between two points of ``space``: half the box along
    periodic axes, all of it between walls."""
    return float(np.linalg.norm(np.where(space.walls, space.lengths, space.lengths / 2)))


class VelocityCorrelation(Analysis):
    """Connected velocity correlation function and its first zero.

    Parameters
    ----------
    r_max
        Largest distance (default: half the smallest box side; the whole side between walls).
    dr
        Bin width (default: ``min(0.5, r_max / 20)``).
    method
        ``"auto"``, ``"cells"`` (exact) or ``"grid"`` (FFT); see the module.
    start, frames
        The window.
    """

    _keys = ("r", "correlation", "pairs", "correlation_length", "r_max_used", "method_used", "num_frames")

    def __init__(self, r_max=None, dr=None, method="auto", start=None, frames=None):
        self.r_max = positive("r_max", r_max, allow_none=True)
        self.dr = positive("dr", dr, allow_none=True)
        if method not in METHODS:
            raise ParameterError(f"method: must be one of {', '.join(METHODS)} (got {method!r})")
        if self.r_max is not None and self.dr is not None and self.dr > self.r_max:
            raise ParameterError(f"dr: must be at most r_max = {self.r_max} (got {self.dr})")
        snapshots.window_start(start, [0], 1)
        self.method, self.start, self.frames = method, start, snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"r_max": self.r_max, "dr": self.dr, "method": self.method, "start": self.start,
                "frames": self.frames}

    r = result("r", "Bin centres.")
    correlation = result("correlation", "C(r); NaN in a bin without pairs.")
    pairs = result("pairs", "Number of ordered pairs i != j per bin, over all frames.")
    correlation_length = result("correlation_length", "First zero of C(r).")
    r_max_used = result("r_max_used", "The largest distance of C(r).")
    du_squared = result("du_squared", "``sum_i |du_i|^2`` over all frames (the sum rule's right side).")
    method_used = result("method_used", "'cells' or 'grid'.")
    num_frames = result("num_frames", "Number of frames averaged.")

    def compute(self, system) -> VelocityCorrelation:
        frames = snapshots.select(snapshots.as_frames(system), self.start, self.frames)
        first = frames[0]
        r_max = self.r_max if self.r_max is not None else float(np.min(np.where(first.space.walls, first.box,
                                                                                first.box / 2)))
        dr = self.dr if self.dr is not None else min(0.5, r_max / 20)
        nbins = max(int(round(r_max / dr)), 1)
        dr = r_max / nbins
        method = self.method
        if method == "auto":
            density = first.n / np.prod(first.box)
            span = 3 * r_max  # a cell and its neighbours
            work = first.n * density * np.prod(np.minimum(span, first.box))
            method = "cells" if work < 3e8 else "grid"
        sums, counts, du2 = np.zeros(nbins), np.zeros(nbins), 0.0
        for f in frames:
            u = f.require_headings("VelocityCorrelation")
            du = u - u.mean(axis=0)
            if method == "cells":
                s, c = cell_sums(f.space, f.positions, du, r_max, nbins)
            else:
                s, c = grid_sums(f.space, f.positions, du, r_max, dr)
            sums += s
            counts += c
            du2 += float((du * du).sum())
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = sums / counts
        r = (np.arange(nbins) + 0.5) * dr
        length = first_zero(r, corr)
        notes = pair_notes(first.space, "no pair")
        empty = int((counts == 0).sum())
        if empty == nbins:
            notes.append(f"no pair of particles closer than r_max = {r_max:.4g}: C(r) is NaN everywhere, and so "
                         "is the correlation length")
        elif math.isnan(length):
            notes.append(f"correlation length: NaN, C(r) stays positive up to r_max = {r_max:.4g} (no zero "
                         f"crossing): the correlations reach further; give a larger r_max (at most "
                         f"{reach(first.space):.4g}, the farthest two particles can be)")
        if 0 < empty < nbins:
            notes.append(f"C(r): NaN in {empty} of {nbins} bins, which hold no pair")
        self._store(r=r, correlation=corr, pairs=counts, correlation_length=length, r_max_used=r_max, du_squared=du2,
                    method_used=method, num_frames=len(frames), notes=notes)
        return self

    def plot(self, ax=None, theme=None):
        """``C(r)`` with its first zero marked."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        ax.plot(self.r, self.correlation, "-", lw=1.2, color=colours[0], label="$C(r)$")
        ax.axhline(0, color=colours[-1], lw=0.6)
        if math.isfinite(self.correlation_length):
            ax.axvline(self.correlation_length, color=colours[1], ls="--", lw=1,
                       label=rf"first zero $r_0 = {self.correlation_length:.3g}$")
        style.label_axes(ax, "r", "corr")
        legend(ax, theme)
        return ax
