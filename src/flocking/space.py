"""The space a flock lives in, for code that works on whole arrays: the analysis, the
pictures, the playground.

:class:`Space` holds a box (one side per axis), which axes are closed by walls, the
obstacles, and where the box starts (``origin``: 0 in the engine's coordinates, ``-L/2``
in a GSD frame's centred ones). Its methods apply the engine's own rules
(:mod:`flocking.rules.geometry`, compiled into NumPy ufuncs and numba kernels), so a
distance measured by the analysis is the distance the engine used: the minimum image
along periodic axes only, nothing across a wall. Obstacles hide nothing (the engine's
neighbours see across them); :meth:`Space.in_obstacle` and
:meth:`Space.boxes_touch_obstacle` say where they are.

>>> space = Space(box=(10.0, 10.0), walls=(False, True))
>>> space.displacement([[1.0, 1.0]], [[9.0, 9.0]]).tolist()  # x wraps, y does not
[[-2.0, 8.0]]
>>> space.wrap([[-1.0, 12.0]]).tolist()  # only periodic axes are folded
[[9.0, 12.0]]
>>> pairs = space.pairs([[0.5, 0.5], [9.5, 0.5], [0.5, 9.5]], cutoff=2.0)  # across x = 0, not across the walls
>>> pairs.i.tolist(), pairs.j.tolist(), pairs.distance.tolist()
([0], [1], [1.0])
>>> pillar = Model(n=10, box=8.0, obstacles=[{"centre": [4, 4], "radius": 1}])
>>> Space.of(pillar).in_obstacle([[4.5, 4.0], [1, 1]]).tolist()
[True, False]
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numba
import numpy as np

from .model import Model
from .rules import compile as compile_rules

_R = compile_rules("cpu")
_jit = numba.njit(cache=True)
_pjit = numba.njit(cache=True, parallel=True)

#: pairs handed out at a time by :meth:`Space.pair_blocks` (about 100 MB of arrays)
BLOCK_PAIRS = 1 << 22


def _minimum_image(dx, length, half):
    return _R.minimum_image(dx, length, half)


def _wrap(x, length):
    return _R.wrap(x, length)


@functools.cache
def _ufuncs() -> tuple:
    """:func:`flocking.rules.geometry.minimum_image` and ``wrap`` as NumPy ufuncs
    (broadcasting), made on first use: made at import, they cost every command that never
    measures a distance a third of a second (loading them from numba's cache included)."""
    return (numba.vectorize(["float64(float64, float64, float64)"], cache=True)(_minimum_image),
            numba.vectorize(["float64(float64, float64)"], cache=True)(_wrap))


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
    (cells numbered with z fastest); ``shape`` (3,): cells per axis; ``near`` (cells, 27):
    the distinct cells within one of each cell along every axis (across periodic sides,
    never across a wall), ``-1`` past the last; ``lengths`` and ``half`` (3,): the box and
    how far a displacement reaches before it is folded (infinite along walls)."""

    points: np.ndarray
    order: np.ndarray
    start: np.ndarray
    shape: np.ndarray
    near: np.ndarray
    lengths: np.ndarray
    half: np.ndarray


@dataclasses.dataclass(frozen=True)
class Space:
    """A box of sides ``box``, closed by walls along the axes where ``walls`` is true,
    with ``obstacles`` (rows ``(*centre, radius)`` in the same coordinates as the points),
    spanning ``[origin, origin + box)`` along each axis."""

    box: tuple[float, ...]
    walls: tuple[bool, ...] | None = None
    obstacles: tuple[tuple[float, ...], ...] = ()
    origin: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        box = tuple(float(x) for x in np.ravel(self.box))
        put("box", box)
        put("walls", (False,) * len(box) if self.walls is None else tuple(bool(w) for w in self.walls))
        put("origin", (0.0,) * len(box) if self.origin is None else tuple(float(x) for x in np.ravel(self.origin)))
        rows = np.asarray(self.obstacles, dtype=np.float64).reshape(-1, len(box) + 1)
        put("obstacles", tuple(tuple(float(x) for x in row) for row in rows))
        if len(self.walls) != len(box) or len(self.origin) != len(box):
            raise ValueError("Space: box, walls and origin need one entry per axis")

    @classmethod
    def of(cls, model: Model, centred: bool = False) -> Space:
        """The space of ``model``: in the engine's coordinates ``[0, L)``, or (``centred``)
        in a GSD frame's, ``[-L/2, L/2)``."""
        shift = -np.asarray(model.box) / 2 if centred else np.zeros(model.dim)
        rows = [(*(np.asarray(o.centre) + shift), o.radius) for o in model.obstacles]
        return cls(model.box, model.walls, tuple(rows), tuple(shift))

    @classmethod
    def of_frame(cls, frame) -> Space:
        """The space of a :class:`flocking.Frame`, in its centred coordinates.

        >>> import flocking
        >>> frame = flocking.Frame(0, 2, [8, 4], np.zeros((1, 3)), np.zeros((1, 3)), walls=[False, True],
        ...                        obstacles=[[1.0, 0.0, 0.5]])
        >>> space = Space.of_frame(frame)
        >>> space.origin, space.walls, space.with_origin(0.0).obstacles
        ((-4.0, -2.0), (False, True), ((5.0, 2.0, 0.5),))
        """
        lengths = np.asarray(frame.box_lengths, dtype=np.float64)
        rows = np.asarray(frame.obstacles, dtype=np.float64).reshape(-1, len(lengths) + 1)
        return cls(tuple(lengths), tuple(frame.walls), tuple(map(tuple, rows)), tuple(-lengths / 2))

    def with_origin(self, origin) -> Space:
        """The same space in coordinates shifted so that the box starts at ``origin``
        (a number or one per axis); obstacle centres move with them."""
        origin = np.broadcast_to(np.asarray(origin, dtype=np.float64), (self.dim,))
        shift = origin - np.asarray(self.origin)
        rows = [(*(np.asarray(row[:-1]) + shift), row[-1]) for row in self.obstacles]
        return Space(self.box, self.walls, tuple(rows), tuple(origin))

    @property
    def dim(self) -> int:
        return len(self.box)

    @property
    def lengths(self) -> np.ndarray:
        return np.asarray(self.box)

    @property
    def half(self) -> np.ndarray:
        """How far a displacement reaches before it is folded: ``L/2`` along periodic
        axes, infinite along axes with walls."""
        return np.where(self.walls, np.inf, self.lengths / 2)

    @property
    def periodic(self) -> np.ndarray:
        return ~np.asarray(self.walls)

    @property
    def volume(self) -> float:
        return math.prod(self.box)

    def displacement(self, a: Sequence, b: Sequence) -> np.ndarray:
        """``b - a`` (broadcast over leading axes), folded to the nearest image along
        periodic axes; points must lie in the box."""
        d = np.asarray(b, dtype=np.float64) - np.asarray(a, dtype=np.float64)
        return _ufuncs()[0](d, self.lengths, self.half)

    def distance(self, a: Sequence, b: Sequence) -> np.ndarray:
        """``|b - a|`` by :meth:`displacement`."""
        d = self.displacement(a, b)
        return np.sqrt(np.sum(d * d, axis=-1))

    def wrap(self, points: Sequence) -> np.ndarray:
        """Points folded into ``[origin, origin + L)`` along periodic axes; coordinates
        along axes with walls are left as they are."""
        x = np.asarray(points, dtype=np.float64)
        origin = np.asarray(self.origin)
        folded = _ufuncs()[1](x - origin, self.lengths) + origin
        return np.where(self.periodic, folded, x)

    def inside(self, points: Sequence) -> np.ndarray:
        """Points brought into the box: :meth:`wrap` along periodic axes, clipped to
        ``[origin, origin + L]`` along walls (a file's float32 rounding can leave a
        particle on a wall a hair outside).

        >>> Space((4.0, 4.0), walls=(False, True)).inside([[4.0, 4.0000001], [-1.0, -0.0001]]).tolist()
        [[0.0, 4.0], [3.0, 0.0]]
        """
        x = self.wrap(points)
        origin = np.asarray(self.origin)
        return np.where(self.periodic, x, np.clip(x, origin, origin + self.lengths))

    def in_obstacle(self, points: Sequence) -> np.ndarray:
        """Whether each point lies strictly inside an obstacle: its squared distance to
        the centre (nearest image) below the radius squared."""
        x = np.asarray(points, dtype=np.float64)
        inside = np.zeros(x.shape[:-1], dtype=bool)
        for row in self.obstacles:
            d = self.displacement(np.asarray(row[:-1]), x)
            inside |= np.sum(d * d, axis=-1) < row[-1] * row[-1]
        return inside

    def obstacle_images(self) -> np.ndarray:
        """Every obstacle and each of its periodic images that reaches into the box, rows
        ``(*centre, radius)`` in this space's coordinates, sorted by centre: what a
        picture draws (an obstacle across a periodic side shows on both).

        >>> Space((10.0, 10.0), walls=(False, True), obstacles=[(9.5, 5.0, 1.0)]).obstacle_images().tolist()
        [[-0.5, 5.0, 1.0], [9.5, 5.0, 1.0]]
        """
        rows = np.asarray(self.obstacles, dtype=np.float64).reshape(-1, self.dim + 1)
        if not len(rows):
            return rows
        middle = np.asarray(self.origin) + self.lengths / 2
        images = []
        for shift in self.image_shifts():
            moved = rows.copy()
            moved[:, :-1] += shift
            reaches = np.all(np.abs(moved[:, :-1] - middle) - moved[:, -1:] < self.lengths / 2, axis=1)
            images.append(moved[reaches])
        out = np.concatenate(images)
        return out[np.lexsort(out.T[::-1])]

    def image_shifts(self) -> np.ndarray:
        """The shifts to a point's image in the neighbouring boxes (and 0) along periodic
        axes, rows of ``dim``."""
        images = np.array(np.meshgrid(*[(-1, 0, 1) if p else (0,) for p in self.periodic], indexing="ij"))
        return images.reshape(self.dim, -1).T * self.lengths

    def clear_obstacles(self, points: np.ndarray, headings: np.ndarray, margin: float) -> int:
        """Move every point strictly inside an obstacle (nearest image) to ``margin``
        outside its surface, along the line from the centre (``-heading`` from the centre
        itself), and turn a heading that points inward back out by reflection; in place.
        Returns how many points moved. What a playground does to the particles an
        obstacle is dropped on; a step's bounce is the engine's rule, not this.

        >>> space = Space((10.0, 10.0), obstacles=[(5.0, 5.0, 2.0)])
        >>> x, u = np.array([[5.5, 5.0], [9.0, 9.0]]), np.array([[-1.0, 0.0], [1.0, 0.0]])
        >>> space.clear_obstacles(x, u, 1e-6), x[0].round(5).tolist(), u[0].tolist()
        (1, [7.0, 5.0], [1.0, 0.0])
        """
        moved = 0
        for row in self.obstacles:
            centre, radius = np.asarray(row[:-1]), row[-1]
            r = self.displacement(centre, points)
            dist = np.sqrt(np.einsum("ij,ij->i", r, r))
            inside = np.flatnonzero(dist < radius)
            if not inside.size:
                continue
            u, dist = headings[inside], dist[inside, None]
            normal = np.where(dist > 0.0, r[inside] / np.where(dist > 0.0, dist, 1.0), -u)
            points[inside] = self.wrap(centre + (radius + margin) * normal)
            dot = np.einsum("ij,ij->i", u, normal)[:, None]
            headings[inside] = np.where(dot < 0.0, u - 2.0 * dot * normal, u)
            moved += inside.size
        return moved

    def boxes_touch_obstacle(self, lower: np.ndarray, side: float) -> np.ndarray:
        """Whether each cube of side ``side`` with lower corner ``lower`` (rows, in this
        space's coordinates, inside the box) overlaps an obstacle or one of its periodic
        images: the point of the cube nearest the obstacle's centre is inside it.

        >>> space = Space((10.0, 10.0), obstacles=[(0.5, 5.0, 1.0)])
        >>> space.boxes_touch_obstacle(np.array([[1.0, 5.0], [8.0, 5.0], [9.0, 5.0], [3.0, 3.0]]), 1.0).tolist()
        [True, False, True, False]
        """
        lower = np.asarray(lower, dtype=np.float64).reshape(-1, self.dim)
        touch = np.zeros(len(lower), dtype=bool)
        for row in self.obstacles:
            centre, radius = np.asarray(row[:-1]), row[-1]
            for shift in self.image_shifts():
                c = centre + shift
                nearest = np.clip(c, lower, lower + side)
                touch |= np.sum((nearest - c) ** 2, axis=1) < radius * radius
        return touch

    def grid(self, samples: int = 1 << 20) -> np.ndarray:
        """About ``samples`` points on a regular grid over the box (cell centres, in this
        space's coordinates), for measuring areas such as the one obstacles cover.

        >>> space = Space((10.0, 10.0), obstacles=[(5.0, 5.0, 2.0)])
        >>> points = space.grid(10000)
        >>> len(points), round(float(space.in_obstacle(points).mean()), 3), round(math.pi * 2.0**2 / 10.0**2, 3)
        (10000, 0.126, 0.126)
        """
        per_axis = max(int(round(samples ** (1 / self.dim))), 1)
        axes = [o + (np.arange(per_axis) + 0.5) * (length / per_axis) for o, length in zip(self.origin, self.box)]
        return np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)

    def cells(self, points: Sequence, cutoff: float) -> CellList:
        """The :class:`CellList` of ``points`` (in this space's coordinates) for pairs
        closer than ``cutoff``: cells at least ``cutoff`` wide, at most about four per
        point. With fewer than three cells along a periodic axis a cell's neighbours are
        listed once, so each pair is seen once, at its minimum image (even when
        ``cutoff`` exceeds half the box)."""
        x = self.inside(points) - np.asarray(self.origin)
        n = len(x)
        shape = cell_shape(self.lengths, cutoff, n)
        pos = np.zeros((n, 3))
        pos[:, : self.dim] = x
        lengths = np.ones(3)
        lengths[: self.dim] = self.lengths
        half = np.full(3, np.inf)
        half[: self.dim] = self.half
        periodic = np.zeros(3, dtype=np.bool_)
        periodic[: self.dim] = self.periodic
        start, order = _sort(pos, shape / lengths, shape)
        return CellList(np.ascontiguousarray(pos[order]), order, start, shape, _near(shape, periodic), lengths, half)

    def pair_blocks(self, points: Sequence, cutoff: float, block: int = BLOCK_PAIRS) -> Iterator[Pairs]:
        """Every pair of ``points`` strictly closer than ``cutoff`` (minimum image along
        periodic axes, none across a wall), once each, in :class:`Pairs` of at most
        about ``block`` pairs (more only where one cell holds more)."""
        cl = self.cells(points, cutoff)
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

    def pair_histogram(self, points: Sequence, cutoff: float, bins: int, vectors=None) -> tuple[np.ndarray, ...]:
        """Over the pairs of :meth:`pair_blocks` (each once), by distance in ``bins``
        equal bins of ``[0, cutoff)``: ``(counts, sums)``, ``sums`` the sum of
        ``vectors[i] . vectors[j]`` (rows, one per point; zeros when not given). A pair
        histogram in one parallel pass, with no list of pairs.

        >>> points, vectors = [[0.5, 0.5], [9.5, 0.5], [0.5, 9.0]], [[1, 0], [1, 1], [2, 0]]
        >>> Space((10.0, 10.0)).pair_histogram(points, 2.0, 4, vectors)  # distances 1, 1.5 and 1.8
        (array([0., 0., 1., 2.]), array([0., 0., 1., 4.]))
        """
        cl = self.cells(points, cutoff)
        vectors = np.zeros((len(cl.order), 1)) if vectors is None else np.asarray(vectors, dtype=np.float64)
        vectors = np.ascontiguousarray(vectors.reshape(len(cl.order), -1)[cl.order])
        chunks = int(min(len(cl.start) - 1, 8 * numba.get_num_threads()))
        counts, sums = _pair_histogram(cl.points, vectors, cl.start, cl.near, cl.lengths, cl.half, float(cutoff),
                                       int(bins), chunks)
        return counts, sums

    def pairs(self, points: Sequence, cutoff: float) -> Pairs:
        """Every pair of ``points`` strictly closer than ``cutoff``, once each (see
        :meth:`pair_blocks`), ``i < j``."""
        blocks = list(self.pair_blocks(points, cutoff))
        return Pairs(*(np.concatenate([getattr(b, name) for b in blocks]) for name in Pairs._fields))


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


@_jit
def _sort(pos, inv, shape):
    """``(start, order)``: a counting sort of the points by cell (the engine's
    :func:`~flocking.rules.geometry.cell_index` along each axis)."""
    n = pos.shape[0]
    cell = np.empty(n, np.int64)
    for i in range(n):
        c = 0
        for a in range(3):
            c = c * shape[a] + _R.cell_index(pos[i, a], inv[a], shape[a])
        cell[i] = c
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
    for c in range(ncell):
        home = (c // (shape[1] * shape[2]), (c // shape[2]) % shape[1], c % shape[2])
        m = 0
        for k in range(27):
            d = 0
            ok = True
            for a in range(3):
                x = home[a] + (k // 3 ** (2 - a)) % 3 - 1
                if periodic[a]:
                    x %= shape[a]
                elif x < 0 or x >= shape[a]:
                    ok = False
                d = d * shape[a] + x
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


@_pjit
def _pair_counts(pos, start, near, lengths, half, cutoff2):
    """Pairs closer than the cutoff that each cell owns: those with points in a cell of
    no lower index (in its own cell, with a point of a later slot)."""
    ncell = len(start) - 1
    counts = np.zeros(ncell, np.int64)
    for c in numba.prange(ncell):
        m = 0
        for k in range(near.shape[1]):
            c2 = near[c, k]
            if c2 < c:
                continue
            for i in range(start[c], start[c + 1]):
                for j in range(i + 1 if c2 == c else start[c2], start[c2 + 1]):
                    if _distance2(pos, i, j, lengths, half) < cutoff2:
                        m += 1
        counts[c] = m
    return counts


@_pjit
def _pair_fill(pos, order, start, near, lengths, half, cutoff2, first, last, offsets, out_i, out_j, out_r):
    """The pairs of cells ``first .. last - 1`` (as :func:`_pair_counts` counts them),
    each cell's from ``offsets[cell]``, as indices into the points given (smaller first)."""
    for c in numba.prange(first, last):
        m = offsets[c]
        for k in range(near.shape[1]):
            c2 = near[c, k]
            if c2 < c:
                continue
            for i in range(start[c], start[c + 1]):
                for j in range(i + 1 if c2 == c else start[c2], start[c2 + 1]):
                    r2 = _distance2(pos, i, j, lengths, half)
                    if r2 < cutoff2:
                        a, b = order[i], order[j]
                        out_i[m], out_j[m] = min(a, b), max(a, b)
                        out_r[m] = math.sqrt(r2)
                        m += 1


@_pjit
def _pair_histogram(pos, vec, start, near, lengths, half, cutoff, nbins, nchunks):
    """Per chunk of cells, pair counts and sums of ``vec_i . vec_j`` per distance bin
    (pairs as :func:`_pair_counts` counts them), then summed over the chunks in order."""
    ncell = len(start) - 1
    counts = np.zeros((nchunks, nbins))
    sums = np.zeros((nchunks, nbins))
    cutoff2 = cutoff * cutoff
    scale = nbins / cutoff
    for chunk in numba.prange(nchunks):
        for c in range(chunk * ncell // nchunks, (chunk + 1) * ncell // nchunks):
            for k in range(near.shape[1]):
                c2 = near[c, k]
                if c2 < c:
                    continue
                for i in range(start[c], start[c + 1]):
                    for j in range(i + 1 if c2 == c else start[c2], start[c2 + 1]):
                        r2 = _distance2(pos, i, j, lengths, half)
                        if r2 < cutoff2:
                            b = min(int(math.sqrt(r2) * scale), nbins - 1)
                            dot = 0.0
                            for a in range(vec.shape[1]):
                                dot += vec[i, a] * vec[j, a]
                            counts[chunk, b] += 1.0
                            sums[chunk, b] += dot
    return counts.sum(axis=0), sums.sum(axis=0)
