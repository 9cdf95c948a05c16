"""Reading trajectories: ``flocking.open(path)`` gives frames that freud and friends accept.

Any GSD file in HOOMD conventions can be read, ours or another program's. A
:class:`Frame` has a freud-style ``box`` (``[Lx, Ly, Lz, xy, xz, yz]``, ``Lz = 0`` in 2D),
``points`` centred in the box (``(N, 3)`` float32, as freud wants), unit ``headings`` and
``velocities``; unpacking it gives ``(box, points)``, which every freud compute accepts.
It also knows its particles' species as GSD types (``typeid`` per particle, ``types``
their names: one type ``"A"`` when the file has none, as HOOMD, freud and OVITO assume)
and the run's ``walls`` (per axis) and ``obstacles`` (rows: centre in the frame's centred
coordinates, then radius), which ``flocking`` writes in frame 0 and every frame carries.

This module reads data and draws nothing, so that the analysis and the pictures can both
read it: a notebook shows frames and trajectories as pictures through ``_repr_png_`` and
``_repr_html_``, which the package (``flocking/__init__.py``) joins to :mod:`flocking.viz`.

>>> import flocking, tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "t.gsd")
>>> sim = flocking.Simulation(flocking.Model(n=10, box=5.0))
>>> sim.writers.append(flocking.GSDWriter(path, every=2))
>>> sim.run(4)
>>> with flocking.open(path) as traj:  # doctest: +ELLIPSIS
...     print(traj)
...     len(traj), traj[-1].step, traj[-1].points.shape, traj.model.n, 0 <= traj[-1].polar_order <= 1
Trajectory('.../t.gsd', frames=3, steps 0..4, n=10, dim=2, box=[5.0, 5.0])
(3, 4, (10, 3), 10, True)
>>> traj  # doctest: +ELLIPSIS
Trajectory('.../t.gsd', closed)
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator

import gsd.hoomd
import numpy as np

from .model import Model

#: Name of the log entry (frame 0) that holds the run's parameters as JSON text.
PARAMETERS_KEY = "flocking/parameters"
#: Log entries (frame 0) of the walls (uint8 per axis) and obstacles (centre, radius rows).
WALLS_KEY = "flocking/walls"
OBSTACLES_KEY = "flocking/obstacles"


class Frame:
    """One frame: step, box, positions, headings and velocities of every particle, their
    species (``typeid`` into ``types``), and the box's ``walls`` and ``obstacles``.

    >>> frame = Frame(0, 2, [8, 8], np.zeros((3, 3)), np.zeros((3, 3)), typeid=[0, 1, 1], types=["A", "B"],
    ...               walls=[True, False], obstacles=[[1.0, 2.0, 0.5]])
    >>> frame.types, frame.typeid.tolist(), frame.walls, frame.obstacles.tolist()
    (('A', 'B'), [0, 1, 1], (True, False), [[1.0, 2.0, 0.5]])
    >>> Frame(0, 2, [8, 8], np.zeros((3, 3)), np.zeros((3, 3))).types   # a file without species
    ('A',)
    """

    def __init__(self, step: int, dim: int, box_lengths, points: np.ndarray, velocities: np.ndarray,
                 typeid=None, types=None, walls=None, obstacles=None):
        self.step = int(step)
        self.dim = int(dim)
        self.box_lengths = np.asarray(box_lengths, dtype=np.float64)[:dim]
        self.points = np.asarray(points, dtype=np.float32)
        self.velocities = np.asarray(velocities, dtype=np.float32)
        n = len(self.points)
        self.typeid = np.zeros(n, np.uint32) if typeid is None else np.asarray(typeid, dtype=np.uint32)
        self.types = ("A",) if types is None else tuple(str(t) for t in types)
        if self.typeid.shape != (n,) or (n and int(self.typeid.max()) >= len(self.types)):
            raise ValueError(f"typeid: must be {n} indices into the {len(self.types)} types")
        self.walls = (False,) * self.dim if walls is None else tuple(bool(w) for w in np.ravel(walls))[: self.dim]
        self.obstacles = (np.zeros((0, self.dim + 1)) if obstacles is None
                          else np.asarray(obstacles, dtype=np.float64).reshape(-1, self.dim + 1))

    @property
    def n(self) -> int:
        return len(self.points)

    @property
    def box(self) -> np.ndarray:
        """freud's box convention: ``[Lx, Ly, Lz, xy, xz, yz]`` with ``Lz = 0`` in 2D."""
        box = np.zeros(6)
        box[: self.dim] = self.box_lengths
        return box

    @property
    def positions(self) -> np.ndarray:
        """``(N, d)`` positions centred in the box (``[-L/2, L/2)``)."""
        return self.points[:, : self.dim]

    @property
    def speeds(self) -> np.ndarray:
        return np.linalg.norm(self.velocities[:, : self.dim].astype(np.float64), axis=1)

    @property
    def headings(self) -> np.ndarray:
        """``(N, d)`` unit headings, from the velocities."""
        v = self.velocities[:, : self.dim].astype(np.float64)
        norm = np.linalg.norm(v, axis=1, keepdims=True)
        return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)

    @property
    def polar_order(self) -> float:
        """``|sum of the headings| / N``, in [0, 1] (0 for an empty frame)."""
        return float(np.linalg.norm(self.headings.sum(axis=0)) / self.n) if self.n else 0.0

    def __iter__(self) -> Iterator:
        """``box, points = frame``: the ``(box, points)`` pair that freud accepts."""
        return iter((self.box, self.points))

    def __repr__(self) -> str:
        return f"Frame(step={self.step}, n={self.n}, dim={self.dim}, box={self.box_lengths.tolist()})"


def static_parts(chunks: dict, dim: int) -> dict:
    """The ``types``, ``typeid``, ``walls`` and ``obstacles`` arguments of a :class:`Frame`
    from GSD chunks named as :func:`flocking.writers.static_chunks` names them (missing
    ones are left to the frame's defaults).

    >>> from flocking import Model
    >>> from flocking.writers import static_chunks
    >>> parts = static_parts(static_chunks(Model(n=3, box=8.0, boundary="wall", species=[{"n": 1}, {"n": 2}])), 2)
    >>> parts["types"], parts["typeid"].tolist(), parts["walls"]
    (['A', 'B'], [0, 1, 1], (True, True))
    """
    parts = {}
    if "particles/types" in chunks:
        parts["types"] = _type_names(chunks["particles/types"])
    if "particles/typeid" in chunks:
        parts["typeid"] = np.asarray(chunks["particles/typeid"])
    walls = chunks.get("log/" + WALLS_KEY)
    if walls is not None:
        parts["walls"] = tuple(bool(w) for w in np.ravel(walls)[:dim])
    obstacles = chunks.get("log/" + OBSTACLES_KEY)
    if obstacles is not None:
        parts["obstacles"] = np.asarray(obstacles, dtype=np.float64).reshape(-1, dim + 1)
    return parts


def _type_names(types) -> list[str]:
    """Type names from gsd.hoomd (a list of str) or a raw ``particles/types`` chunk (int8 rows)."""
    if isinstance(types, (list, tuple)):
        return [str(t) for t in types]
    rows = np.asarray(types).view(np.uint8).reshape(len(types), -1)
    return [bytes(row).split(b"\0", 1)[0].decode() for row in rows]


class Trajectory:
    """The frames of a GSD file, read lazily; index, slice or iterate it."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self._file = gsd.hoomd.open(self.path, mode="r")
        self._closed = False
        self._geometry = None

    def __len__(self) -> int:
        return len(self._file)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return read_frame(self._file[index], self.geometry)

    @property
    def gsd(self) -> gsd.hoomd.HOOMDTrajectory:
        """The open ``gsd.hoomd`` trajectory this reads (every chunk of the file)."""
        return self._file

    @property
    def geometry(self) -> dict:
        """The ``walls`` and ``obstacles`` arguments of every :class:`Frame`, read from
        frame 0 once (empty for a file without them)."""
        if self._geometry is None:
            self._geometry = geometry_of(self._file)
        return self._geometry

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    @property
    def model(self) -> Model | None:
        """The parameters stored by ``flocking`` (``None`` for other programs' files)."""
        params = self.parameters
        return None if params is None else Model.from_dict(params["model"])

    @property
    def parameters(self) -> dict | None:
        """Everything the run recorded about itself (model, steps, backend, ...)."""
        if len(self) == 0:
            return None
        log = self._file[0].log
        if PARAMETERS_KEY not in log:
            return None
        return json.loads(np.asarray(log[PARAMETERS_KEY], dtype=np.uint8).tobytes().decode())

    def __repr__(self) -> str:
        if self._closed:
            return f"Trajectory({self.path!r}, closed)"
        if len(self) == 0:
            return f"Trajectory({self.path!r}, frames=0)"
        first, last = self[0], self[-1]
        return (f"Trajectory({self.path!r}, frames={len(self)}, steps {first.step}..{last.step}, "
                f"n={last.n}, dim={last.dim}, box={last.box_lengths.tolist()})")

    def close(self) -> None:
        self._file.close()
        self._closed = True

    def __enter__(self) -> Trajectory:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def geometry_of(frames: gsd.hoomd.HOOMDTrajectory) -> dict:
    """The ``walls`` and ``obstacles`` of a ``gsd.hoomd`` trajectory, from the log of
    its frame 0, as :class:`Frame` arguments (empty when it has none)."""
    if len(frames) == 0:
        return {}
    first = frames[0]
    log = {"log/" + key: value for key, value in first.log.items()}
    parts = static_parts(log, int(first.configuration.dimensions))
    return {key: parts[key] for key in ("walls", "obstacles") if key in parts}


def read_frame(f: gsd.hoomd.Frame, geometry: dict | None = None) -> Frame:
    """A :class:`Frame` of a ``gsd.hoomd`` frame, with the run's ``geometry`` (the
    ``walls`` and ``obstacles`` of :func:`geometry_of`)."""
    dim = int(f.configuration.dimensions)
    box = np.asarray(f.configuration.box, dtype=np.float64)
    n = int(f.particles.N)
    points = np.zeros((n, 3), np.float32) if f.particles.position is None else f.particles.position
    velocities = f.particles.velocity
    if velocities is None or not np.any(velocities):
        # HOOMD active-matter files often carry orientations and no velocities: the
        # heading is the body x axis, rotated by the quaternion (w, x, y, z)
        q = f.particles.orientation
        velocities = np.zeros((n, 3), np.float32) if q is None else _body_x_axis(q)
    # gsd.hoomd gives every frame frame 0's types and type ids, or ["A"] and zeros
    types, typeid = f.particles.types, f.particles.typeid
    if typeid is None or len(typeid) != n:
        typeid = np.zeros(n, np.uint32)
    types = _type_names(types) if types else ["A"]
    types += [str(i) for i in range(len(types), int(np.max(typeid, initial=0)) + 1)]  # ids without a name
    return Frame(f.configuration.step, dim, box[:3], points, velocities, typeid=typeid, types=types,
                 **(geometry or {}))


def _body_x_axis(q: np.ndarray) -> np.ndarray:
    """The image of (1, 0, 0) under each unit quaternion ``(w, x, y, z)``."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1).astype(np.float32)


def open(path: str | os.PathLike) -> Trajectory:  # noqa: A001 - mirrors gsd.hoomd.open
    """Open a GSD trajectory for reading."""
    return Trajectory(path)
