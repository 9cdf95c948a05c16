"""Reading trajectories: ``flocking.open(path)`` gives frames that freud and friends accept.

Any GSD file in HOOMD conventions can be read, ours or another program's. A
:class:`Frame` has a freud-style ``box`` (``[Lx, Ly, Lz, xy, xz, yz]``, ``Lz = 0`` in 2D),
``points`` centred in the box (``(N, 3)`` float32, as freud wants), unit ``headings`` and
``velocities``; unpacking it gives ``(box, points)``, which every freud compute accepts.

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


class Frame:
    """One frame: step, box, positions, headings and velocities of every particle."""

    def __init__(self, step: int, dim: int, box_lengths, points: np.ndarray, velocities: np.ndarray):
        self.step = int(step)
        self.dim = int(dim)
        self.box_lengths = np.asarray(box_lengths, dtype=np.float64)[:dim]
        self.points = np.asarray(points, dtype=np.float32)
        self.velocities = np.asarray(velocities, dtype=np.float32)

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

    def _repr_png_(self) -> bytes:
        """A notebook shows a frame as a picture."""
        from .viz.notebook import frame_png

        return frame_png(self)

    def __repr__(self) -> str:
        return f"Frame(step={self.step}, n={self.n}, dim={self.dim}, box={self.box_lengths.tolist()})"


class Trajectory:
    """The frames of a GSD file, read lazily; index, slice or iterate it."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self._file = gsd.hoomd.open(self.path, mode="r")
        self._closed = False

    def __len__(self) -> int:
        return len(self._file)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        return _frame(self._file[index])

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

    def _repr_html_(self) -> str:
        """A notebook plays a trajectory as a small H.264 video."""
        from .viz.notebook import trajectory_html

        return trajectory_html(self)

    def close(self) -> None:
        self._file.close()
        self._closed = True

    def __enter__(self) -> Trajectory:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _frame(f: gsd.hoomd.Frame) -> Frame:
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
    return Frame(f.configuration.step, dim, box[:3], points, velocities)


def _body_x_axis(q: np.ndarray) -> np.ndarray:
    """The image of (1, 0, 0) under each unit quaternion ``(w, x, y, z)``."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1).astype(np.float32)


def open(path: str | os.PathLike) -> Trajectory:  # noqa: A001 - mirrors gsd.hoomd.open
    """Open a GSD trajectory for reading."""
    return Trajectory(path)
