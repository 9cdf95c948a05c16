"""Everything a quantity accepts, turned into a sequence of :class:`Snapshot`.

Accepted systems: a :class:`flocking.Trajectory` (``flocking.open``), a GSD path or a run
folder holding ``trajectory.gsd``, any ``gsd.hoomd`` trajectory or frame (HOOMD
conventions, ours or another program's), a :class:`flocking.Frame`, a ``(box, points)``
or ``(box, points, velocities)`` tuple (``box`` a number, one length per axis, freud's
``[Lx, Ly, Lz, xy, xz, yz]`` with ``Lz = 0`` in 2D, a ``freud.box.Box``, or a
:class:`flocking.space.Space` with walls and obstacles), or a list of any of these frames.
A flocking file's frames bring their walls and obstacles; other boxes are periodic.
Positions are brought into the box in double precision (wrapped along periodic axes);
each snapshot keeps the ``origin`` (lower corner) of the box in the input's own
coordinates, so that results given as positions (the slabs of a density profile) read in
them: ``-L/2`` for GSD files, frames and freud boxes (centred, HOOMD's convention); a
space's own origin; for a plain box, 0 when every point lies in ``[0, L]``, else ``-L/2``
when every point lies in ``[-L/2, L/2]`` (else 0, and the points are wrapped).

>>> import numpy as np
>>> frames = as_frames((10.0, np.array([[1.0, 2.0], [-4.0, 4.5]])))
>>> len(frames), frames[0].dim, frames[0].positions.tolist(), frames[0].origin.tolist()
(1, 2, [[6.0, 7.0], [1.0, 9.5]], [-5.0, -5.0])
"""

from __future__ import annotations

import functools
import math
import numbers
import os
from collections.abc import Sequence

import numpy as np

from ..model import Model, ParameterError
from ..space import Space
from ..trajectory import Frame, Trajectory, geometry_of, read_frame


class Snapshot:
    """One frame as the analysis sees it: ``step``; ``space``, the
    :class:`~flocking.space.Space` (box, walls, obstacles) with its corner at 0;
    ``positions`` (N, d) in it as float64 (``[0, L)`` along periodic axes, ``[0, L]``
    between walls); unit ``headings`` (N, d) or ``None`` when no velocity is known;
    ``origin`` (d,): where the input's coordinates put the box's lower corner (the input's
    position ``x`` is ``origin + positions``, modulo the box); and the particle types
    (species) when the input has them: ``types`` (names) and ``typeid`` (N,), else ``None``.
    ``space`` is given in the input's coordinates (a bare box length or lengths: periodic,
    at the corner)."""

    __slots__ = ("step", "space", "box", "positions", "headings", "origin", "typeid", "types")

    def __init__(self, step: int, space, positions, headings=None, typeid=None, types=None):
        if not isinstance(space, Space):
            space = Space(tuple(np.broadcast_to(np.asarray(space, dtype=np.float64), (np.shape(positions)[1],))))
        self.step = int(step)
        self.origin = np.asarray(space.origin)
        self.space = space.with_origin(0.0)
        self.box = self.space.lengths
        self.positions = self.space.inside(np.asarray(positions, dtype=np.float64) - self.origin)
        self.headings = None if headings is None else unit(headings)
        self.typeid = None if typeid is None else np.asarray(typeid, dtype=np.int64)
        self.types = None if types is None else tuple(str(t) for t in types)

    @property
    def dim(self) -> int:
        return len(self.box)

    @property
    def n(self) -> int:
        return len(self.positions)

    def require_headings(self, who: str) -> np.ndarray:
        if self.headings is None:
            raise ParameterError(f"system: {who} needs velocities, and this frame has none")
        return self.headings

    def members(self, species: str) -> np.ndarray:
        """Boolean mask of the particles of type ``species`` (a name of :attr:`types`)."""
        if self.types is None or self.typeid is None:
            raise ParameterError("system: holds no particle types, so no species (a GSD file's particles/types "
                                 "and particles/typeid)")
        if species not in self.types:
            raise ParameterError(f"species: must be one of {', '.join(self.types)} (got {species!r})")
        return self.typeid == self.types.index(species)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


class Frames(Sequence):
    """A lazy, indexable sequence of snapshots (a trajectory is read frame by frame);
    ``model`` is the :class:`~flocking.Model` stored in a flocking trajectory, else ``None``."""

    def __init__(self, items, convert, steps=None, model: Model | None = None):
        self._items = items
        self._convert = convert
        self._steps = steps
        self.model = model

    def __len__(self) -> int:
        return len(self._items)

    def __getitem__(self, index):
        if isinstance(index, slice):
            steps = None if self._steps is None else self._steps[index]
            return Frames(_Sliced(self._items, range(len(self))[index]), self._convert, steps, self.model)
        return self._convert(self._items[index])

    @property
    def steps(self) -> np.ndarray:
        """The step of every frame (read without loading particle data where possible)."""
        if self._steps is None:
            self._steps = np.array([self[i].step for i in range(len(self))], dtype=np.int64)
        return self._steps


class _Sliced:
    def __init__(self, items, indices: range):
        self._items, self._indices = items, indices

    def __len__(self):
        return len(self._indices)

    def __getitem__(self, i):
        return self._items[self._indices[i]]


def _box_from(box, ncols: int) -> tuple[np.ndarray, bool]:
    """``(side lengths, centred)``: ``centred`` when the box follows freud's convention."""
    if hasattr(box, "Lx") and hasattr(box, "is2D"):  # freud.box.Box and look-alikes
        return np.array([box.Lx, box.Ly] if box.is2D else [box.Lx, box.Ly, box.Lz], dtype=np.float64), True
    freud = False
    if isinstance(box, numbers.Real) and not isinstance(box, bool):
        lengths = np.full(2 if ncols == 2 else 3, float(box))
    else:
        try:
            lengths = np.asarray(box, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise ParameterError(f"box: must be a number, one length per axis or freud's 6-array (got {box!r})")
        if len(lengths) == 6:
            if np.any(lengths[3:] != 0):
                raise ParameterError("box: tilted boxes are not supported (xy, xz, yz must be 0)")
            lengths = lengths[:2] if lengths[2] == 0 else lengths[:3]
            freud = True
        elif len(lengths) == 1:
            lengths = np.full(2 if ncols == 2 else 3, lengths[0])
        elif len(lengths) not in (2, 3):
            raise ParameterError(f"box: must have 1, 2, 3 or 6 entries (got {len(lengths)})")
    if not np.all(np.isfinite(lengths)) or np.any(lengths <= 0):
        raise ParameterError(f"box: side lengths must be positive (got {lengths.tolist()})")
    return lengths, freud


def from_box_points(box, points, velocities=None, step: int = 0) -> Snapshot:
    """A snapshot from a box (or a :class:`~flocking.space.Space`) and an ``(N, 2)`` or
    ``(N, 3)`` array of points."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3) or len(points) == 0:
        raise ParameterError(f"points: must be a non-empty (N, 2) or (N, 3) array (got shape {points.shape})")
    if not np.all(np.isfinite(points)):
        raise ParameterError("points: must be finite")
    if isinstance(box, Space):
        space = box
        lengths = space.lengths
    else:
        lengths, centred = _box_from(box, points.shape[1])
        if points.shape[1] >= len(lengths) and not centred:
            inside = points[:, : len(lengths)]
            if not np.all((inside >= 0) & (inside <= lengths)):
                centred = bool(np.all(np.abs(inside) <= lengths / 2))
        space = Space(tuple(lengths), origin=tuple(-lengths / 2 if centred else np.zeros(len(lengths))))
    dim = len(lengths)
    if points.shape[1] < dim:
        raise ParameterError(f"points: a {dim}D box needs {dim} columns (got {points.shape[1]})")
    headings = None
    if velocities is not None:
        velocities = np.asarray(velocities, dtype=np.float64)
        if velocities.shape[0] != len(points) or velocities.ndim != 2 or velocities.shape[1] < dim:
            raise ParameterError(f"velocities: must have shape ({len(points)}, {dim}) (got {velocities.shape})")
        headings = velocities[:, :dim]
    return Snapshot(step, space, points[:, :dim], headings)


def from_frame(frame: Frame, typeid=None, types=None) -> Snapshot:
    """A snapshot of a :class:`flocking.Frame`, with its walls and obstacles; its types
    are the frame's ``typeid`` and ``types`` where it has them, else those given."""
    v = frame.velocities[:, : frame.dim].astype(np.float64)
    headings = v if np.any(v) else None
    if getattr(frame, "typeid", None) is not None:  # frames that carry their types
        typeid, types = frame.typeid, frame.types
    return Snapshot(frame.step, Space.of_frame(frame), frame.positions.astype(np.float64), headings, typeid, types)


def from_gsd_frame(frame, geometry: dict | None = None) -> Snapshot:
    """A snapshot of a ``gsd.hoomd.Frame``, with its particle types (``particles/typeid``
    is read from frame 0 where later frames leave it out, as gsd does) and the run's
    ``geometry`` (walls and obstacles: :func:`flocking.trajectory.geometry_of`)."""
    particles = frame.particles
    return from_frame(read_frame(frame, geometry), particles.typeid, particles.types)


def _from_any_frame(item) -> Snapshot:
    if isinstance(item, Snapshot):
        return item
    if isinstance(item, Frame):
        return from_frame(item)
    if hasattr(item, "configuration") and hasattr(item, "particles"):  # a gsd.hoomd.Frame
        return from_gsd_frame(item)
    if isinstance(item, tuple) and len(item) in (2, 3):
        return from_box_points(*item)
    raise ParameterError(f"system: cannot read a frame from {type(item).__name__}; give a trajectory, "
                         "a GSD path, a Frame, a (box, points) pair or a list of these")


def _is_box_points(system) -> bool:
    return (isinstance(system, tuple) and len(system) in (2, 3) and not _looks_like_frame(system[0])
            and np.ndim(system[1]) == 2)


def _looks_like_frame(x) -> bool:
    return isinstance(x, (Frame, Snapshot, tuple)) or (hasattr(x, "configuration") and hasattr(x, "particles"))


def trajectory_path(path) -> str:
    """A GSD file, or the ``trajectory.gsd`` of a run folder."""
    path = os.fspath(path)
    if os.path.isdir(path):
        path = os.path.join(path, "trajectory.gsd")
        if not os.path.exists(path):
            raise ParameterError(f"system: folder {os.path.dirname(path)!r} holds no trajectory.gsd")
    elif not os.path.exists(path):
        raise ParameterError(f"system: no such file or folder {path!r}")
    return path


def as_frames(system) -> Frames:
    """Normalise any accepted system to a lazy sequence of snapshots."""
    if isinstance(system, Frames):
        return system
    if isinstance(system, (str, os.PathLike)):
        path = trajectory_path(system)
        try:
            traj = Trajectory(path)
        except Exception as err:  # gsd raises several kinds for a file that is not GSD
            raise ParameterError(f"system: {path!r} is not a readable GSD file ({err})") from None
        return as_frames(traj)
    if isinstance(system, Trajectory):  # read through its gsd file, which holds the particle types
        convert = functools.partial(from_gsd_frame, geometry=system.geometry)
        return Frames(system.gsd, convert, _gsd_steps(system.gsd), _stored_model(system))
    if hasattr(system, "file") and hasattr(system, "__getitem__") and hasattr(system, "__len__"):
        # a gsd.hoomd trajectory: its frames, with the walls and obstacles of its frame 0
        convert = functools.partial(from_gsd_frame, geometry=geometry_of(system))
        return Frames(system, convert, _gsd_steps(system))
    if _is_box_points(system) or _looks_like_frame(system):
        return Frames([system], _from_any_frame)
    if isinstance(system, (list, tuple)):
        if len(system) == 0:
            raise ParameterError("system: the list of frames is empty")
        return Frames(list(system), _from_any_frame)
    raise ParameterError(f"system: cannot read frames from {type(system).__name__}; give a trajectory, "
                         "a GSD path, a Frame, a (box, points) pair or a list of these")


def _gsd_steps(handle):
    """Frame steps read from the ``configuration/step`` chunks alone (``None`` if that fails)."""
    try:
        f = handle.file
        steps = []
        for i in range(len(handle)):
            chunk = f.read_chunk(frame=i, name="configuration/step") if f.chunk_exists(
                frame=i, name="configuration/step") else None
            steps.append(int(chunk[0]) if chunk is not None else 0)
        return np.array(steps, dtype=np.int64)
    except Exception:  # an unusual reader: fall back to reading frames
        return None


def _stored_model(traj: Trajectory) -> Model | None:
    try:
        return traj.model
    except Exception:  # parameters written by another version: analyse as a foreign file
        return None


def model_of(system) -> Model | None:
    """The stored :class:`~flocking.Model` of a flocking trajectory, path, run folder or
    :class:`Frames`."""
    if isinstance(system, Frames):
        return system.model
    if isinstance(system, Trajectory):
        return _stored_model(system)
    if isinstance(system, (str, os.PathLike)):
        try:
            with Trajectory(trajectory_path(system)) as traj:
                return _stored_model(traj)
        except Exception:
            return None
    return None


def steps_within_half(model: Model, length: float) -> int:
    """The most steps over which the run's particles (speed ``v0 dt`` per step at most)
    move less than ``length / 2``: how far apart frames can be to be followed.

    >>> steps_within_half(Model(n=10, box=16.0, speed=0.5), 16.0)
    15
    """
    return max(math.ceil(length / 2 / (model.speed * model.dt)) - 1, 0)


def time_step(dt, model: Model | None) -> float:
    """The time step to turn steps into time: ``dt`` when given, else the run's, else 1."""
    if dt is not None:
        return dt
    return model.dt if model is not None else 1.0


def select(frames: Frames, start=None, count=None) -> Frames:
    """The frames of a window: ``start`` a step (frames with ``step >= start``) or, when
    ``0 < start < 1``, the fraction of frames to discard; then at most the last ``count``."""
    n = len(frames)
    first = window_start(start, frames.steps if start is not None and not 0 < start < 1 else None, n)
    chosen = frames[first:]
    if count is not None:
        chosen = chosen[max(0, len(chosen) - count):]
    if len(chosen) == 0:
        raise ParameterError(f"start: no frame left after start={start!r} (the last frame is at step "
                             f"{int(frames.steps[-1])})")
    return chosen


def window_start(start, steps, n: int) -> int:
    """Index of the first kept item for ``start`` (a step, or a fraction in (0, 1))."""
    if start is None:
        return 0
    if isinstance(start, bool) or not isinstance(start, numbers.Real) or not math.isfinite(start) or start < 0:
        raise ParameterError(f"start: must be a step >= 0 or a fraction in (0, 1) (got {start!r})")
    if 0 < start < 1:
        return int(math.floor(start * n))
    if start != int(start):
        raise ParameterError(f"start: must be a whole step >= 0 or a fraction in (0, 1) (got {start!r})")
    return int(np.searchsorted(np.asarray(steps), int(start), side="left"))


def check_count(name: str, value):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ParameterError(f"{name}: must be a whole number >= 1 (got {value!r})")
    return int(value)
