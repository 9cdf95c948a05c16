"""The space a flock lives in, for code that works on whole arrays: the analysis, the
pictures, the playground.

:class:`Space` holds a box (one side per axis), which axes are closed by walls, the
obstacles, and where the box starts (``origin``: 0 in the engine's coordinates, ``-L/2``
in a GSD frame's centred ones). Its methods apply the engine's own rules
(:mod:`flocking.rules.geometry`, compiled into NumPy ufuncs and numba kernels), so a
distance measured by the analysis is the distance the engine used: the minimum image
along periodic axes only, nothing across a wall. Obstacles hide nothing (the engine's
neighbours see across them); :meth:`Space.in_obstacle` and
:meth:`Space.boxes_touch_obstacle` say where they are. :meth:`Space.neighbours` answers
questions about one set of points (pairs within a distance, the k nearest) from cell lists
it builds once (:mod:`flocking.neighbour_query`).

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

import numba
import numpy as np

from .model import Model
from .neighbour_query import BLOCK_PAIRS, CellList, NeighbourQuery, Pairs
from .rules import compile as compile_rules
from .rules import rebind, source_digest
from .rules.geometry import reach

_R = compile_rules("cpu")


def _minimum_image(dx, length, half):
    return _R.minimum_image(dx, length, half)


def _wrap(x, length):
    return _R.wrap(x, length)


@functools.cache
def _ufuncs() -> tuple:
    """:func:`flocking.rules.geometry.minimum_image` and ``wrap`` as NumPy ufuncs
    (broadcasting), made on first use: made at import, they cost every command that never
    measures a distance a third of a second (loading them from numba's cache included).
    Cached under names with :func:`flocking.rules.source_digest`, so that a changed rule
    is compiled again."""
    digest = source_digest()
    return (numba.vectorize(["float64(float64, float64, float64)"], cache=True)(
                rebind(_minimum_image, globals(), f"_minimum_image_{digest}")),
            numba.vectorize(["float64(float64, float64)"], cache=True)(rebind(_wrap, globals(), f"_wrap_{digest}")))


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
        return np.array([reach(length, wall) for length, wall in zip(self.box, self.walls)])

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
        """Whether each point lies strictly inside an obstacle (any of :meth:`inside_each`)."""
        return self.inside_each(points).any(axis=0)

    def inside_each(self, points: Sequence) -> np.ndarray:
        """Whether each point lies strictly inside each obstacle, ``(obstacles, *points)``:
        its squared distance to the centre (nearest image) below the radius squared.

        >>> space = Space((10.0, 10.0), obstacles=[(5.0, 5.0, 2.0), (0.5, 0.5, 1.0)])
        >>> space.inside_each([[6.0, 5.0], [9.8, 9.8], [7.0, 5.0]]).tolist()
        [[True, False, False], [False, True, False]]
        """
        x = np.asarray(points, dtype=np.float64)
        out = np.zeros((len(self.obstacles), *x.shape[:-1]), dtype=bool)
        for k, row in enumerate(self.obstacles):
            out[k] = self._inside(row, x)
        return out

    def _inside(self, row: Sequence[float], x: np.ndarray) -> np.ndarray:
        d = self.displacement(np.asarray(row[:-1]), x)
        return np.sum(d * d, axis=-1) < row[-1] * row[-1]

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
            inside = np.flatnonzero(self._inside(row, points))
            if not inside.size:
                continue
            r = self.displacement(centre, points[inside])
            u, dist = headings[inside], np.sqrt(np.einsum("ij,ij->i", r, r))[:, None]
            normal = np.where(dist > 0.0, r / np.where(dist > 0.0, dist, 1.0), -u)
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

    def neighbours(self, points: Sequence) -> NeighbourQuery:
        """A :class:`~flocking.neighbour_query.NeighbourQuery` over ``points`` (in this
        space's coordinates): pairs within a distance and the k nearest, its cell lists
        built once and kept for every question asked of it."""
        return NeighbourQuery(self, points)

    def cells(self, points: Sequence, cutoff: float) -> CellList:
        """The :class:`~flocking.neighbour_query.CellList` of ``points`` for pairs closer
        than ``cutoff`` (see :meth:`NeighbourQuery.cells`)."""
        return self.neighbours(points).cells(cutoff)

    def pair_blocks(self, points: Sequence, cutoff: float, block: int = BLOCK_PAIRS) -> Iterator[Pairs]:
        """Every pair of ``points`` strictly closer than ``cutoff`` (minimum image along
        periodic axes, none across a wall), once each, in :class:`Pairs` of at most
        about ``block`` pairs (more only where one cell holds more)."""
        return self.neighbours(points).pair_blocks(cutoff, block)

    def pair_histogram(self, points: Sequence, cutoff: float, bins: int, vectors=None) -> tuple[np.ndarray, ...]:
        """Pair counts and sums of ``vectors[i] . vectors[j]`` by distance in ``bins``
        equal bins of ``[0, cutoff)`` (see :meth:`NeighbourQuery.pair_histogram`).

        >>> points, vectors = [[0.5, 0.5], [9.5, 0.5], [0.5, 9.0]], [[1, 0], [1, 1], [2, 0]]
        >>> Space((10.0, 10.0)).pair_histogram(points, 2.0, 4, vectors)  # distances 1, 1.5 and 1.8
        (array([0., 0., 1., 2.]), array([0., 0., 1., 4.]))
        """
        return self.neighbours(points).pair_histogram(cutoff, bins, vectors)

    def pairs(self, points: Sequence, cutoff: float) -> Pairs:
        """Every pair of ``points`` strictly closer than ``cutoff``, once each (see
        :meth:`pair_blocks`), ``i < j``."""
        return self.neighbours(points).within(cutoff)
