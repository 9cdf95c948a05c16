"""Neighbours of a frame's points: pairs within a distance and the k nearest, from cell
lists built once and kept.

A :class:`NeighbourQuery` is made by :meth:`flocking.space.Space.neighbours` for one set
of points. Its distances are the engine's (the minimum image along periodic axes, none
across a wall; obstacles hide nothing), its cells are numbered as the engine numbers them
(:func:`flocking.rules.geometry.cell_number`), and :meth:`NeighbourQuery.nearest` is the
topological model's own rule (:func:`flocking.rules.neighbours.knearest`), so a
neighbour found here is a neighbour the engine would find. Each cell list is built on the
first question that needs it and kept: a frame asked for its clusters and its
correlations, or for pairs at one distance twice, is sorted into cells once per cell
width.

>>> from flocking.space import Space
>>> query = Space((10.0, 10.0)).neighbours([[0.5, 0.5], [9.5, 0.5], [0.5, 9.0], [5.0, 5.0]])
>>> pairs = query.within(2.0)  # across x = 0 and across y = 0, each pair once, in no set order
>>> sorted(zip(pairs.i.tolist(), pairs.j.tolist(), pairs.distance.round(3).tolist()))
[(0, 1, 1.0), (0, 2, 1.5), (1, 2, 1.803)]
>>> indices, distances = query.nearest(2)  # nearest first, ties to the lower index
>>> indices[0].tolist(), distances[0].tolist()
([1, 2], [1.0, 1.5])
>>> query.within(2.0) is not None, query.cell_lists
(True, 2)
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numba
import numpy as np

from .checks import ParameterError, integer, real
from .rules import cached
from .rules import compile as compile_rules

_R = compile_rules("cpu")
_jit = cached()
_pjit = cached(parallel=True)

#: pairs handed out at a time by :meth:`NeighbourQuery.pair_blocks` (about 100 MB of arrays)
BLOCK_PAIRS = 1 << 22
#: chunks of cells a pair histogram is summed in (fixed, so that its last bits do not
#: depend on the number of threads)
HISTOGRAM_CHUNKS = 64


class Pairs(NamedTuple):
    """Pairs of points closer than a cutoff, each once: indices ``i < j`` into the points
    given, and their ``distance`` (minimum image along periodic axes)."""

    i: np.ndarray
    j: np.ndarray
    distance: np.ndarray


class CellList(NamedTuple):
    """Points sorted into cells at least ``cutoff`` wide, in three dimensions (a 2D space
    has one cell along z, where every point sits at 0), for kernels that visit pairs.

    ``points`` (N, 3): relative to the box's corner, in slot order; ``order`` (N,): the
    index of the point in each slot; ``start`` (cells + 1,): the first slot of each cell
    (cells numbered by :func:`flocking.rules.geometry.cell_number`, x fastest); ``shape``
    (3,): cells per axis; ``near`` (cells, 27): the distinct cells within one of each cell
    along every axis (across periodic sides, never across a wall), ``-1`` past the last;
    ``lengths`` and ``half`` (3,): the box and how far a displacement reaches before it is
    folded (infinite along walls)."""

    points: np.ndarray
    order: np.ndarray
    start: np.ndarray
    shape: np.ndarray
    near: np.ndarray
    lengths: np.ndarray
    half: np.ndarray


def cell_shape(lengths: np.ndarray, cutoff: float, n: int) -> np.ndarray:
    """Cells per axis (3 entries, 1 beyond the dimension): at least ``cutoff`` wide, at
    most about ``max(4 n, 64)`` in all.

    >>> cell_shape(np.array([10.0, 3.0]), 1.0, 100).tolist(), cell_shape(np.array([100.0, 100.0]), 1.0, 10).tolist()
    ([10, 3, 1], [6, 6, 1])
    """
    cells = np.maximum(np.floor(np.asarray(lengths, float) / cutoff), 1).astype(np.int64)
    while np.prod(cells) > max(4 * n, 64):
        cells = np.maximum(cells // 2, 1)
    return np.concatenate([cells, np.ones(3 - len(cells), np.int64)])


class NeighbourQuery:
    """The neighbours of ``points`` (rows of ``space.dim`` coordinates, in ``space``'s
    coordinates: periodic axes are folded, walls clip) in ``space``, a
    :class:`flocking.space.Space` (this module does not import it: it is what
    imports this one).

    Questions: :meth:`within` (every pair closer than a distance), :meth:`pair_blocks`
    (the same in pieces of bounded memory), :meth:`pair_histogram` (pair counts and sums
    by distance, with no list of pairs) and :meth:`nearest` (the k nearest others of each
    point). Distances are in the units of the coordinates."""

    def __init__(self, space, points: Sequence) -> None:
        x = np.asarray(points, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != space.dim:
            raise ParameterError(f"points: must be rows of {space.dim} coordinates (got shape {x.shape})")
        self.space = space
        self.n = len(x)
        self._x = space.inside(x) - np.asarray(space.origin)
        self._lists: dict[tuple[int, ...], CellList] = {}

    @property
    def cell_lists(self) -> int:
        """How many cell lists this query has built (one per cell width asked for)."""
        return len(self._lists)

    def cells(self, cutoff: float) -> CellList:
        """The :class:`CellList` for pairs closer than ``cutoff``: cells at least
        ``cutoff`` wide, at most about four per point, built on first use. With fewer
        than three cells along a periodic axis a cell's neighbours are listed once, so
        each pair is seen once, at its minimum image (even when ``cutoff`` exceeds half
        the box)."""
        space = self.space
        shape = cell_shape(space.lengths, real("cutoff", cutoff, low=0.0, low_open=True), self.n)
        key = tuple(int(s) for s in shape)
        if key not in self._lists:
            dim = space.dim
            pos = np.zeros((self.n, 3))
            pos[:, :dim] = self._x
            lengths, half, periodic = np.ones(3), np.full(3, np.inf), np.zeros(3, dtype=np.bool_)
            lengths[:dim], half[:dim], periodic[:dim] = space.lengths, space.half, space.periodic
            start, order = _sort(pos, shape / lengths, shape)
            self._lists[key] = CellList(np.ascontiguousarray(pos[order]), order, start, shape,
                                        _near(shape, periodic), lengths, half)
        return self._lists[key]

    def pair_blocks(self, cutoff: float, block: int = BLOCK_PAIRS) -> Iterator[Pairs]:
        """Every pair strictly closer than ``cutoff``, once each, in :class:`Pairs` of
        at most about ``block`` pairs (more only where one cell holds more)."""
        cl = self.cells(cutoff)
        cutoff2 = float(cutoff) ** 2
        counts = _pair_counts(cl.points, cl.start, cl.near, cl.lengths, cl.half, cutoff2)
        ends = np.cumsum(counts)
        first = 0
        while first < len(counts):
            base = int(ends[first - 1]) if first else 0
            last = max(int(np.searchsorted(ends, base + block, side="right")), first + 1)
            size = int(ends[last - 1]) - base
            out_i, out_j, out_r = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size)
            _pair_fill(cl.points, cl.order, cl.start, cl.near, cl.lengths, cl.half, cutoff2, first, last,
                       ends - counts - base, out_i, out_j, out_r)
            yield Pairs(out_i, out_j, out_r)
            first = last

    def within(self, cutoff: float) -> Pairs:
        """Every pair strictly closer than ``cutoff``, once each, ``i < j``."""
        blocks = list(self.pair_blocks(cutoff))
        return Pairs(*(np.concatenate([getattr(b, name) for b in blocks]) for name in Pairs._fields))

    def pair_histogram(self, cutoff: float, bins: int, vectors=None) -> tuple[np.ndarray, np.ndarray]:
        """Over the pairs closer than ``cutoff`` (each once), by distance in ``bins``
        equal bins of ``[0, cutoff)``: ``(counts, sums)``, ``sums`` the sum of
        ``vectors[i] . vectors[j]`` (rows, one per point; zeros when not given). One
        parallel pass, no list of pairs; the same result whatever the number of threads."""
        bins = integer("bins", bins, 1)
        cl = self.cells(cutoff)
        vectors = np.zeros((self.n, 1)) if vectors is None else np.asarray(vectors, dtype=np.float64)
        vectors = np.ascontiguousarray(vectors.reshape(self.n, -1)[cl.order])
        chunks = int(min(len(cl.start) - 1, HISTOGRAM_CHUNKS))
        return _pair_histogram(cl.points, vectors, cl.start, cl.near, cl.lengths, cl.half, float(cutoff), bins,
                               chunks)

    def nearest(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest others of every point: ``(indices, distances)``, each
        ``(N, k)``, nearest first, ties to the lower index. The engine's rule for
        topological neighbours (:func:`flocking.rules.neighbours.knearest`), searched by
        rings of cells that hold about ``k / 2`` (3D) to ``2 k / 3`` (2D) points each."""
        k = integer("k", k, 1)
        if k > self.n - 1:
            raise ParameterError(f"k: must be at most the number of other points, {self.n - 1} (got {k})")
        space = self.space
        width = (k * space.volume / self.n) ** (1.0 / space.dim) * 0.8
        cl = self.cells(min(width, float(np.max(space.lengths))))
        pos = np.ascontiguousarray(cl.points.T)
        indices, distances = np.empty((self.n, k), np.int64), np.empty((self.n, k))
        _nearest(pos, cl.order, cl.start, cl.shape, cl.lengths, cl.half, space.dim, k, indices, distances)
        return indices, distances


@_jit
def _sort(pos, inv, shape):
    """``(start, order)``: a counting sort of the points by cell (the engine's
    :func:`~flocking.rules.geometry.cell_index` along each axis)."""
    n = pos.shape[0]
    cell = np.empty(n, np.int64)
    for i in range(n):
        cell[i] = _R.cell_number(_R.cell_index(pos[i, 0], inv[0], shape[0]), _R.cell_index(pos[i, 1], inv[1], shape[1]),
                                 _R.cell_index(pos[i, 2], inv[2], shape[2]), shape[0], shape[1])
    start = np.zeros(shape[0] * shape[1] * shape[2] + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(len(start) - 1):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return start, order


@_jit
def _near(shape, periodic):
    """The distinct cells within one of each cell along every axis: across the sides of
    periodic axes, never past a wall; ``-1`` past the last."""
    ncell = shape[0] * shape[1] * shape[2]
    out = np.full((ncell, 27), -1, np.int64)
    home = np.empty(3, np.int64)
    at = np.empty(3, np.int64)
    for c in range(ncell):
        home[0], home[1], home[2] = _R.cell_coords(c, shape[0], shape[1])
        m = 0
        for k in range(27):
            ok = True
            for a in range(3):
                x = home[a] + (k // 3**a) % 3 - 1
                if periodic[a]:
                    x %= shape[a]
                elif x < 0 or x >= shape[a]:
                    ok = False
                at[a] = x
            d = _R.cell_number(at[0], at[1], at[2], shape[0], shape[1])
            if ok:
                for q in range(m):
                    if out[c, q] == d:
                        ok = False
                if ok:
                    out[c, m] = d
                    m += 1
    return out


@numba.njit(inline="always")
def _distance2(pos, i, j, lengths, half):
    s = 0.0
    for a in range(3):
        d = _R.minimum_image(pos[j, a] - pos[i, a], lengths[a], half[a])
        s += d * d
    return s


@numba.njit(inline="always")
def _cell_pairs(c, pos, start, near, lengths, half, cutoff2, action, a, b, d, e, m):
    """The pairs closer than the cutoff that cell ``c`` owns: those with points in a cell
    of no lower number (in its own cell, with a point of a later slot). Each is handed to
    ``m = action(a, b, d, e, m, i, j, r2)`` (slots ``i``, ``j``, squared distance
    ``r2``; ``a, b, d, e`` what the action writes to, four arguments rather than a tuple
    so that the parallel loops see the arrays written); returns the last ``m``."""
    for k in range(near.shape[1]):
        c2 = near[c, k]
        if c2 < c:
            continue
        for i in range(start[c], start[c + 1]):
            for j in range(i + 1 if c2 == c else start[c2], start[c2 + 1]):
                r2 = _distance2(pos, i, j, lengths, half)
                if r2 < cutoff2:
                    m = action(a, b, d, e, m, i, j, r2)
    return m


@numba.njit(inline="always")
def _count(a, b, d, e, m, i, j, r2):
    return m + 1


@numba.njit(inline="always")
def _store(order, out_i, out_j, out_r, m, i, j, r2):
    """Pair ``m``, as point indices (smaller first) and its distance."""
    p, q = order[i], order[j]
    out_i[m], out_j[m] = min(p, q), max(p, q)
    out_r[m] = math.sqrt(r2)
    return m + 1


@numba.njit(inline="always")
def _bin(vec, counts, sums, scale, m, i, j, r2):
    """One count and ``vec_i . vec_j`` in the pair's distance bin (``scale``: bins per
    unit length)."""
    b = min(int(math.sqrt(r2) * scale), len(counts) - 1)
    dot = 0.0
    for a in range(vec.shape[1]):
        dot += vec[i, a] * vec[j, a]
    counts[b] += 1.0
    sums[b] += dot
    return m


@_pjit
def _pair_counts(pos, start, near, lengths, half, cutoff2):
    """The number of pairs each cell owns (:func:`_cell_pairs`)."""
    ncell = len(start) - 1
    counts = np.zeros(ncell, np.int64)
    for c in numba.prange(ncell):
        counts[c] = _cell_pairs(c, pos, start, near, lengths, half, cutoff2, _count, 0, 0, 0, 0, 0)
    return counts


@_pjit
def _pair_fill(pos, order, start, near, lengths, half, cutoff2, first, last, offsets, out_i, out_j, out_r):
    """The pairs of cells ``first .. last - 1`` (:func:`_cell_pairs`), each cell's from
    ``offsets[cell]``, as indices into the points given (smaller first)."""
    for c in numba.prange(first, last):
        _cell_pairs(c, pos, start, near, lengths, half, cutoff2, _store, order, out_i, out_j, out_r, offsets[c])


@_pjit
def _pair_histogram(pos, vec, start, near, lengths, half, cutoff, nbins, nchunks):
    """Per chunk of cells, pair counts and sums of ``vec_i . vec_j`` per distance bin
    (pairs as :func:`_cell_pairs` gives them), then summed over the chunks in order."""
    ncell = len(start) - 1
    counts = np.zeros((nchunks, nbins))
    sums = np.zeros((nchunks, nbins))
    cutoff2 = cutoff * cutoff
    scale = nbins / cutoff
    for chunk in numba.prange(nchunks):
        for c in range(chunk * ncell // nchunks, (chunk + 1) * ncell // nchunks):
            _cell_pairs(c, pos, start, near, lengths, half, cutoff2, _bin, vec, counts[chunk], sums[chunk], scale, 0)
    return counts.sum(axis=0), sums.sum(axis=0)


@_pjit
def _nearest(pos, order, start, shape, lengths, half, dim, k, indices, distances):
    """The ``k`` nearest others of each slot's point by
    :func:`~flocking.rules.neighbours.knearest`, into the rows of ``indices`` and
    ``distances`` of the point's own index (``pos`` (3, N) in slot order)."""
    n = pos.shape[1]
    head = np.zeros((3, n))
    slots = np.empty((n, k), np.int64)
    inv0, inv1, inv2 = shape[0] / lengths[0], shape[1] / lengths[1], shape[2] / lengths[2]
    for i in numba.prange(n):
        row = order[i]
        c0 = _R.cell_index(pos[0, i], inv0, shape[0])
        c1 = _R.cell_index(pos[1, i], inv1, shape[1])
        c2 = _R.cell_index(pos[2, i], inv2, shape[2])
        _R.knearest(i, c0, c1, c2, 0, pos, head, order, start, shape[0], shape[1], shape[2], lengths[0], lengths[1],
                    lengths[2], half[0], half[1], half[2], dim, k, False, 0.0, distances[row], indices[row], slots[row])
        for q in range(k):
            distances[row, q] = math.sqrt(distances[row, q])
