"""The space a flock lives in, for code that works on whole arrays: the analysis, the
pictures, the playground.

:class:`Space` holds a box (one side per axis), which axes are closed by walls, the
obstacles, and where the box starts (``origin``: 0 in the engine's coordinates, ``-L/2``
in a GSD frame's centred ones). Its methods apply the engine's own rules
(:mod:`flocking.rules.geometry`, compiled into NumPy ufuncs), so a distance measured by
the analysis is the distance the engine used: the minimum image along periodic axes
only, nothing across a wall.

>>> space = Space(box=(10.0, 10.0), walls=(False, True))
>>> space.displacement([[1.0, 1.0]], [[9.0, 9.0]]).tolist()  # x wraps, y does not
[[-2.0, 8.0]]
>>> space.wrap([[-1.0, 12.0]]).tolist()  # only periodic axes are folded
[[9.0, 12.0]]
>>> Space.of(Model(n=10, box=8.0, obstacles=[{"centre": [4, 4], "radius": 1}])).in_obstacle([[4.5, 4.0], [1, 1]]).tolist()
[True, False]
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numba
import numpy as np

from .model import Model
from .rules import compile as _compile

_R = _compile("cpu")


def _minimum_image(dx, length, half):
    return _R.minimum_image(dx, length, half)


def _wrap(x, length):
    return _R.wrap(x, length)


#: :func:`flocking.rules.geometry.minimum_image` and ``wrap`` as NumPy ufuncs (broadcasting)
minimum_image = numba.vectorize(["float64(float64, float64, float64)"], cache=True)(_minimum_image)
wrap = numba.vectorize(["float64(float64, float64)"], cache=True)(_wrap)


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
        put("origin", (0.0,) * len(box) if self.origin is None else tuple(float(x) for x in self.origin))
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
        return minimum_image(d, self.lengths, self.half)

    def distance(self, a: Sequence, b: Sequence) -> np.ndarray:
        """``|b - a|`` by :meth:`displacement`."""
        d = self.displacement(a, b)
        return np.sqrt(np.sum(d * d, axis=-1))

    def wrap(self, points: Sequence) -> np.ndarray:
        """Points folded into ``[origin, origin + L)`` along periodic axes; coordinates
        along axes with walls are left as they are."""
        x = np.asarray(points, dtype=np.float64)
        origin = np.asarray(self.origin)
        folded = wrap(x - origin, self.lengths) + origin
        return np.where(self.periodic, folded, x)

    def in_obstacle(self, points: Sequence) -> np.ndarray:
        """Whether each point lies strictly inside an obstacle (nearest image)."""
        x = np.asarray(points, dtype=np.float64)
        inside = np.zeros(x.shape[:-1], dtype=bool)
        for row in self.obstacles:
            inside |= self.distance(np.asarray(row[:-1]), x) < row[-1]
        return inside
