"""The local mean heading around each particle, in 2D and 3D, for colouring pictures.

Headings are summed on a grid of bins (at most :data:`MAX_BINS` per axis) and smoothed
with a Gaussian that holds :data:`LOCAL_COUNT` particles on average, periodic along
periodic axes and cut at walls (the grid is padded with empty bins there, so nothing
wraps around from the other wall); each particle reads the sum in its bin. One
particle's heading is mostly noise; the mean over its surroundings shows the slow,
correlated turns of an ordered flock (:func:`.colors.deviation_colors` colours them).

>>> rng = np.random.default_rng(0)
>>> x = rng.uniform(-4, 4, (4000, 3))
>>> u = np.where(x[:, :1] < 0, [[1.0, 0, 0]], [[0, 1.0, 0]])   # two halves, two headings
>>> local = local_headings(x, u, (8.0, 8.0, 8.0))
>>> bool(np.all(np.abs(local[np.abs(x[:, 0] + 2) < 0.5] - [1, 0, 0]) < 0.05))   # deep in the left half
True
"""

from __future__ import annotations

import math

import numpy as np

#: The smoothing kernel holds this many particles on average.
LOCAL_COUNT = 40.0
#: Bins per axis at most (a bin is about half the kernel's width).
MAX_BINS = 64


def local_headings(positions, headings, box_lengths, walls=None) -> np.ndarray:
    """``(N, d)`` unit vectors: the mean heading around each of ``(N, d)`` particles at
    centred ``positions`` (``[-L/2, L/2)``) with unit ``headings``; ``walls`` per axis
    (default none). A particle alone in its region keeps its own heading."""
    positions = np.asarray(positions, float)
    headings = np.asarray(headings, float)
    n, dim = headings.shape
    box = np.asarray(box_lengths, float)[:dim]
    walls = (False,) * dim if walls is None else tuple(bool(w) for w in walls)[:dim]
    if n == 0:
        return headings.copy()
    # a Gaussian of width sigma averages over (2 pi)^(d/2) sigma^d of space
    sigma = (LOCAL_COUNT * float(np.prod(box)) / n / (2 * math.pi) ** (dim / 2)) ** (1 / dim)
    shape = tuple(int(min(MAX_BINS, max(4, math.ceil(2 * length / sigma)))) for length in box)
    index = [np.clip(((positions[:, a] / box[a] + 0.5) * shape[a]).astype(np.int64), 0, shape[a] - 1)
             for a in range(dim)]
    flat = np.ravel_multi_index(index, shape)
    padded = tuple(2 * s if wall else s for s, wall in zip(shape, walls))
    kernel = _gaussian_ft(padded, [sigma * s / length for s, length in zip(shape, box)])
    local = np.empty_like(headings)
    for c in range(dim):
        grid = np.zeros(padded)
        grid[tuple(slice(0, s) for s in shape)] = np.bincount(flat, weights=headings[:, c],
                                                              minlength=math.prod(shape)).reshape(shape)
        axes = tuple(range(dim))
        smooth = np.fft.irfftn(np.fft.rfftn(grid, axes=axes) * kernel, s=padded, axes=axes)
        local[:, c] = smooth[tuple(slice(0, s) for s in shape)].ravel()[flat]
    norm = np.linalg.norm(local, axis=1, keepdims=True)
    return np.where(norm > 1e-9, local / np.maximum(norm, 1e-300), headings)


def _gaussian_ft(shape, sigmas) -> np.ndarray:
    """Fourier transform (``rfftn`` layout) of a periodic Gaussian on a grid of ``shape``,
    ``sigmas`` bins wide per axis, its weights summing to 1."""
    ft = np.ones(())
    for axis, (size, sigma) in enumerate(zip(shape, sigmas)):
        offset = np.minimum(np.arange(size), size - np.arange(size))  # periodic distance in bins
        g = np.exp(-0.5 * (offset / max(sigma, 1e-9)) ** 2)
        g /= g.sum()
        f = np.fft.rfft(g) if axis == len(shape) - 1 else np.fft.fft(g)
        ft = ft[..., None] * f
    return ft
