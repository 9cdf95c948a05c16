"""The state of a flock: positions, unit headings, speeds and the step counter.

Arrays are in particle-id order. Positions lie in ``[0, L)`` along each axis (the GSD
files centre them, see :mod:`flocking.writers`). Initial states draw their random numbers
from :mod:`flocking.rng`, so they depend on the seed alone.

>>> from flocking import Model, State
>>> s = State.random(Model(n=5, box=4.0, seed=3))
>>> s.positions.shape, s.headings.shape, s.step
((5, 2), (5, 2), 0)
>>> bool(np.allclose(np.linalg.norm(s.headings, axis=1), 1.0))
True
>>> round(State.aligned(Model(n=5, box=4.0)).polar_order(), 12)
1.0
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from . import rng
from .model import Model, ParameterError
from .space import Space

_BLOCK = 1 << 16  # particles drawn at a time by the random constructors


@dataclasses.dataclass
class State:
    """Positions ``(N, d)``, unit headings ``(N, d)``, speeds ``(N,)`` and the step ``t``."""

    positions: np.ndarray
    headings: np.ndarray
    speeds: np.ndarray
    step: int = 0

    def __post_init__(self) -> None:
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float64)
        self.headings = np.ascontiguousarray(self.headings, dtype=np.float64)
        speeds = np.asarray(self.speeds, dtype=np.float64)
        # equal speeds may be one number broadcast to (N,): 0 bytes a particle, read-only
        self.speeds = speeds if speeds.ndim == 1 and speeds.strides == (0,) else np.ascontiguousarray(speeds)
        n, d = self.positions.shape
        if self.headings.shape != (n, d) or self.speeds.shape != (n,):
            raise ValueError("state: positions, headings and speeds disagree in shape")

    @property
    def n(self) -> int:
        return self.positions.shape[0]

    @property
    def dim(self) -> int:
        return self.positions.shape[1]

    def copy(self) -> State:
        return State(self.positions.copy(), self.headings.copy(), self.speeds.copy(), self.step)

    def polar_order(self) -> float:
        """``phi = |sum_i u_i| / N``."""
        return float(np.linalg.norm(self.headings.sum(axis=0)) / self.n)

    # -- constructors -------------------------------------------------------------------

    @classmethod
    def random(cls, model: Model) -> State:
        """Uniform positions in the box (outside every obstacle) and uniformly random headings.

        The arrays are filled a block of particles at a time, so the random numbers'
        temporaries stay small; each number is a pure function of its keys, so the
        blocks change no value.
        """
        n, d = model.n, model.dim
        positions, headings = np.empty((n, d)), np.empty((n, d))
        for lo in range(0, n, _BLOCK):
            ids = np.arange(lo, min(n, lo + _BLOCK), dtype=np.uint64)
            positions[lo : lo + len(ids)] = random_positions(model, ids)
            u0 = rng.uniform(model.seed, 0, ids, rng.HEADING)
            u1 = rng.uniform(model.seed, 0, ids, rng.HEADING + 1)
            headings[lo : lo + len(ids)] = random_unit_vectors(d, u0, u1)
        return cls(positions, headings, initial_speeds(model))

    @classmethod
    def aligned(cls, model: Model) -> State:
        """Uniform positions with every heading along +x."""
        state = cls.random(model)
        state.headings[:] = 0.0
        state.headings[:, 0] = 1.0
        return state

    @classmethod
    def from_gsd(cls, path: str | os.PathLike, model: Model) -> State:
        """The last frame of a GSD trajectory: positions, headings and its step.

        Speeds follow the model (the same seed gives the same per-particle speeds), and
        the box, dimension and particle count of the file must match the model.
        """
        from .trajectory import open as open_trajectory

        try:
            with open_trajectory(path) as traj:
                frame = traj[-1]
        except (OSError, RuntimeError, IndexError, KeyError, ValueError) as err:
            raise ParameterError(f"init: cannot read a frame from {os.fspath(path)!r} ({err})") from None
        if frame.dim != model.dim:
            raise ParameterError(f"init: the file is {frame.dim}D but dim={model.dim}")
        if frame.n != model.n:
            raise ParameterError(f"init: the file has {frame.n} particles but n={model.n}")
        if not np.allclose(frame.box_lengths, model.box, rtol=1e-6):
            raise ParameterError(f"init: the file's box {tuple(frame.box_lengths)} differs from box={model.box}")
        if not (np.isfinite(frame.positions).all() and np.isfinite(frame.headings).all()):
            raise ParameterError(f"init: the last frame of {os.fspath(path)!r} holds NaN or infinite "
                                 "positions or velocities")
        norms = np.linalg.norm(frame.headings, axis=1)
        if not (norms > 0).all():
            raise ParameterError(f"init: the last frame of {os.fspath(path)!r} has particles with zero "
                                 "velocity, so no heading")
        positions = Space.of(model).inside(frame.positions.astype(np.float64) + np.asarray(model.box) / 2)
        headings = frame.headings.astype(np.float64)
        headings /= np.linalg.norm(headings, axis=1, keepdims=True)
        return cls(positions, headings, initial_speeds(model), int(frame.step))


def frame_arrays(state: State, box) -> tuple[np.ndarray, np.ndarray]:
    """Positions centred in the box and ``velocity = speed * heading``, as GSD frames hold
    them: float32 ``(N, 3)``, z = 0 in 2D.

    >>> points, velocities = frame_arrays(State.aligned(Model(n=3, box=4.0, speed=0.5)), (4.0, 4.0))
    >>> points.dtype, points.shape, velocities[0].tolist()
    (dtype('float32'), (3, 3), [0.5, 0.0, 0.0])
    """
    points = np.zeros((state.n, 3), dtype=np.float32)
    points[:, : state.dim] = state.positions - np.asarray(box) / 2
    velocities = np.zeros((state.n, 3), dtype=np.float32)
    velocities[:, : state.dim] = state.speeds[:, None] * state.headings
    return points, velocities


def random_positions(model: Model, ids: np.ndarray) -> np.ndarray:
    """Positions of the particles ``ids`` (uint64), uniform in the free space of the box.

    Draw ``r`` uses the step key ``r`` (0 first) with the counters ``POSITION + axis``: a
    particle inside an obstacle draws again, until it is outside (the obstacles leave at
    least a tenth of the box free, so a few draws do)."""
    box = np.asarray(model.box)
    space = Space.of(model)
    positions = np.empty((len(ids), model.dim))
    todo = np.arange(len(ids))
    draw = 0
    while todo.size:
        for a in range(model.dim):
            positions[todo, a] = rng.uniform(model.seed, draw, ids[todo], rng.POSITION + a) * box[a]
        # u * L can round up to L itself: keep the half-open interval
        positions[todo] = np.where(positions[todo] >= box, 0.0, positions[todo])
        todo = todo[space.in_obstacle(positions[todo])]
        draw += 1
    return positions


def random_unit_vectors(dim: int, u0: np.ndarray, u1: np.ndarray) -> np.ndarray:
    """Unit vectors uniform on the circle (from ``u0``) or the sphere (from ``u0, u1``)."""
    if dim == 2:
        angle = 2.0 * np.pi * u0
        return np.stack([np.cos(angle), np.sin(angle)], axis=1)
    z = 2.0 * u0 - 1.0
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    angle = 2.0 * np.pi * u1
    return np.stack([rho * np.cos(angle), rho * np.sin(angle), z], axis=1)


def initial_speeds(model: Model) -> np.ndarray:
    """All ``v0`` (one number broadcast, read-only), or (``speeds="uniform"``) each
    uniform in ``(0, v0]``; with species, each species' own ``speed`` and ``speeds``."""
    v0s, kinds, counts = model.species_values("speed"), model.species_values("speeds"), model.species_counts
    if len(set(v0s)) == 1 and set(kinds) == {"constant"}:
        return np.broadcast_to(np.float64(v0s[0]), (model.n,))
    speeds = np.empty(model.n)
    first = 0
    for v0, kind, count in zip(v0s, kinds, counts):
        if kind == "constant":
            speeds[first : first + count] = v0
        else:
            for lo in range(first, first + count, _BLOCK):
                ids = np.arange(lo, min(first + count, lo + _BLOCK), dtype=np.uint64)
                speeds[lo : lo + len(ids)] = v0 * (1.0 - rng.uniform(model.seed, 0, ids, rng.SPEED))
        first += count
    return speeds
