"""Writers: objects a :class:`~flocking.Simulation` calls on a trigger while it runs.

A writer has ``every`` (a period in steps, counted from the run's origin; ``0`` means only
the first and the last step of a run), ``begin(sim)`` (called once when a run starts),
``write(sim)`` (at each triggered step), ``observe(steps, phi)`` (the polar order of every
step, in blocks) and ``close()``. Files are flushed as they go, so an interrupted run leaves valid files that
hold everything written so far.

>>> import flocking, tempfile, os
>>> folder = tempfile.mkdtemp()
>>> sim = flocking.Simulation(flocking.Model(n=20, box=4.0))
>>> sim.writers.append(flocking.ObservablesWriter(os.path.join(folder, "obs.csv")))
>>> sim.run(3)
>>> print(open(os.path.join(folder, "obs.csv")).read().splitlines()[0])
step,polar_order
"""

from __future__ import annotations

import json
import os

import gsd.hoomd
import numpy as np

from .trajectory import PARAMETERS_KEY


class Writer:
    """Base class: a writer that does nothing on every trigger."""

    every = 0

    def due(self, step: int, origin: int, last: int) -> bool:
        """Whether ``step`` is triggered: the origin, the last step, or a period from the origin."""
        if step in (origin, last):
            return True
        return self.every > 0 and (step - origin) % self.every == 0

    def begin(self, sim) -> None:
        """Called when a run starts, before the first step."""

    def write(self, sim) -> None:
        """Called at each step where :meth:`due` is true (the first and last included)."""

    def observe(self, steps: np.ndarray, phi: np.ndarray) -> None:
        """Called with the polar order after each step, in blocks."""

    def close(self) -> None:
        """Flush and release files."""


class GSDWriter(Writer):
    """Frames in HOOMD/GSD conventions: positions centred, ``velocity = speed * heading``.

    Frame 0 carries the parameters of the run (log entry ``flocking/parameters``, JSON).
    In 2D the box has ``Lz = 1`` and every z is 0, as HOOMD and MDAnalysis expect; the
    frame's ``configuration.dimensions`` says 2.
    """

    def __init__(self, path: str | os.PathLike, every: int = 100, mode: str = "w"):
        self.path = os.fspath(path)
        self.every = int(every)
        self.mode = mode
        self._file = None
        self._last = None

    def begin(self, sim) -> None:
        if self._file is None:
            self._file = gsd.hoomd.open(self.path, mode=self.mode)
            self._parameters = json.dumps(sim.parameters()).encode()
            if len(self._file):
                self._last = int(self._file[-1].configuration.step)

    def write(self, sim) -> None:
        if self._last is not None and sim.step <= self._last:
            return  # appending to a file that already holds this step
        state = sim.state
        model = sim.model
        frame = gsd.hoomd.Frame()
        frame.configuration.step = state.step
        frame.configuration.dimensions = model.dim
        box = np.zeros(6)
        box[:3] = 1.0
        box[: model.dim] = model.box
        frame.configuration.box = box
        frame.particles.N = state.n
        frame.particles.types = ["A"]
        frame.particles.typeid = np.zeros(state.n, dtype=np.uint32)
        points = np.zeros((state.n, 3), dtype=np.float32)
        points[:, : model.dim] = state.positions - np.asarray(model.box) / 2
        velocities = np.zeros((state.n, 3), dtype=np.float32)
        velocities[:, : model.dim] = state.speeds[:, None] * state.headings
        frame.particles.position = points
        frame.particles.velocity = velocities
        if len(self._file) == 0:
            frame.log[PARAMETERS_KEY] = np.frombuffer(self._parameters, dtype=np.uint8)
        self._file.append(frame)
        self._file.flush()
        self._last = state.step

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class ObservablesWriter(Writer):
    """A CSV table with a header and one row per step: ``step,polar_order``."""

    columns = ("step", "polar_order")

    def __init__(self, path: str | os.PathLike, mode: str = "w"):
        self.path = os.fspath(path)
        self.mode = mode
        self._file = None

    def begin(self, sim) -> None:
        if self._file is None:
            fresh = self.mode == "w" or not os.path.exists(self.path) or os.path.getsize(self.path) == 0
            self._file = open(self.path, self.mode, encoding="utf-8")
            if fresh:
                self._file.write(",".join(self.columns) + "\n")
                self._file.write(f"{sim.step},{sim.state.polar_order()!r}\n")
                self._file.flush()

    def observe(self, steps: np.ndarray, phi: np.ndarray) -> None:
        # one write of whole lines: a crash never leaves half a row behind a flushed one
        self._file.write("".join(f"{s},{p!r}\n" for s, p in zip(steps.tolist(), phi.tolist())))
        self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class CheckpointWriter(Writer):
    """Checkpoints (:meth:`Simulation.save_checkpoint`) every ``every`` steps and at the
    last step, each written atomically over the previous one."""

    def __init__(self, path: str | os.PathLike, every: int = 1000):
        self.path = os.fspath(path)
        self.every = int(every)

    def write(self, sim) -> None:
        sim.save_checkpoint(self.path)
