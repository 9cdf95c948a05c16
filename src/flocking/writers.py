"""Writers: objects a :class:`~flocking.Simulation` calls on a trigger while it runs.

A writer has ``every`` (a period in steps, counted from the run's origin; ``0`` means only
the first and the last step of a run), ``begin(sim)`` (called once when a run starts),
``write(sim)`` (at each triggered step), ``observe(steps, phi, extra)`` (the polar order of
every step, in blocks, and ``extra``, a mapping of the other observables' names to their
values at those steps, or ``None``), ``sync()`` (finish what is in flight; a checkpoint calls it first) and
``close()``. Files are flushed as they go (small GSD frames at least once a second, as
each flush fsyncs), so an interrupted run leaves valid files that hold everything up to
its last second, and everything up to its last checkpoint.

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
import threading
import time

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

    def observe(self, steps: np.ndarray, phi: np.ndarray, extra: dict | None = None) -> None:
        """Called with the polar order after each step, in blocks, and the other observables
        of those steps (:meth:`flocking.Simulation.extra_observables`), if the model has any."""

    def sync(self) -> None:
        """Finish any write still in progress (and raise its error, if it failed)."""

    def close(self) -> None:
        """Flush and release files."""


#: The chunks of a frame, in gsd.hoomd's order, with the value gsd.hoomd leaves out (a
#: reader fills it in): the frame's own chunks are N-sized and all zero by default.
_DEFAULTS = {
    "configuration/step": np.zeros(1, dtype=np.uint64),
    "configuration/dimensions": np.array([3], dtype=np.uint8),
    "configuration/box": np.array([1, 1, 1, 0, 0, 0], dtype=np.float32),
    "particles/N": np.zeros(1, dtype=np.uint32),
    "particles/position": None,
    "particles/velocity": None,
}
_HEAD = 64  # values of frame 0's large chunks kept to tell a frame from it without reading it


class GSDWriter(Writer):
    """Frames in HOOMD/GSD conventions: positions centred, ``velocity = speed * heading``.

    Frame 0 carries the parameters of the run (log entry ``flocking/parameters``, JSON).
    In 2D the box has ``Lz = 1`` and every z is 0, as HOOMD and MDAnalysis expect; the
    frame's ``configuration.dimensions`` says 2.

    Frames go through the file layer (``gsd.fl``) with exactly the chunks that
    ``gsd.hoomd`` would write: a chunk is left out when it equals frame 0's (or, absent
    from frame 0, its default). The arrays come from the backend's ``frame_arrays()``
    (the CPU backend's spare buffers). A large frame (``threaded_from`` particles and up)
    is copied into buffers of the writer (24 bytes a particle) and written by a thread
    while the simulation goes on: disks that take longer to store a frame than the
    simulation takes to compute the next ones no longer set the pace. One frame is in
    flight at most; :meth:`sync` waits for it, and an error in writing it is raised there,
    by the next :meth:`write` or by :meth:`close`.

    gsd's flush makes frames visible to readers and durable (it calls ``fsync``, about a
    millisecond). Large frames, frame 0, and small frames at least ``flush_interval``
    seconds after the last flush are flushed as they are written; :meth:`sync` (which a
    checkpoint calls) and :meth:`close` flush the rest. A run killed outright loses at
    most that last second of small frames, none from before its last checkpoint.
    """

    threaded_from = 1 << 16
    flush_interval = 1.0

    def __init__(self, path: str | os.PathLike, every: int = 100, mode: str = "w"):
        self.path = os.fspath(path)
        self.every = int(every)
        self.mode = mode
        self._file = None
        self._last = None
        self._first: dict[str, np.ndarray] = {}  # frame 0's chunks (the head of large ones)
        self._shapes: dict[str, tuple] = {}
        self._buffers: tuple[np.ndarray, np.ndarray] | None = None  # a frame in flight
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._flushed = 0.0  # time.monotonic() of the last flush
        self._dirty = False  # frames written since

    def begin(self, sim) -> None:
        if self._file is None:
            import gsd.fl
            import gsd.version

            if self.mode == "w" or not os.path.exists(self.path):
                # gsd creates a file with mode 0640 whatever the umask, and keeps the mode of one that
                # exists: made here, it gets the mode of every other output (0644 under umask 022)
                with open(self.path, "wb"):
                    pass
                self.mode = "w"
            self._file = gsd.fl.open(self.path, mode=self.mode, application="gsd.hoomd " + gsd.version.version,
                                     schema="hoomd", schema_version=[2, 0])
            if self._file.schema != "hoomd":
                self._file.close()
                self._file = None
                raise RuntimeError(f"GSD file is not a hoomd schema file: {self.path}")
            self.mode = "a"  # a later run of the same simulation appends to what this one wrote
            self._parameters = np.frombuffer(json.dumps(sim.parameters()).encode(), dtype=np.uint8)
            self._static = static_chunks(sim.model)
            if self._file.nframes:
                for name in _DEFAULTS:
                    if self._file.chunk_exists(frame=0, name=name):
                        self._remember(name, self._file.read_chunk(frame=0, name=name))
                self._last = int(self._read_last("configuration/step")[0])

    def _read_last(self, name: str) -> np.ndarray:
        """A chunk of the last frame, as a reader sees it (from frame 0, or the default)."""
        last = self._file.nframes - 1
        if self._file.chunk_exists(frame=last, name=name):
            return self._file.read_chunk(frame=last, name=name)
        return self._first.get(name, _DEFAULTS[name])

    def _remember(self, name: str, data: np.ndarray) -> None:
        large = _DEFAULTS[name] is None
        self._first[name] = data.reshape(-1)[:_HEAD].copy() if large else data.copy()
        self._shapes[name] = data.shape

    def _differs(self, name: str, data: np.ndarray) -> bool:
        """Whether gsd.hoomd would write ``data``: it differs from frame 0's chunk, or,
        where frame 0 has none, from the default."""
        default = _DEFAULTS[name]
        if name not in self._first:
            return bool(data.any()) if default is None else not np.array_equiv(data, default)
        first = self._first[name]
        if default is None:  # large: compare the head, and only if that matches, all of it
            if data.shape != self._shapes[name] or not np.array_equal(data.reshape(-1)[:_HEAD], first):
                return True
            return not np.array_equal(data, self._file.read_chunk(frame=0, name=name))
        return not np.array_equal(data, first)

    def write(self, sim) -> None:
        if self._last is not None and sim.step <= self._last:
            return  # appending to a file that already holds this step
        self._wait()  # the buffers are free again, and an earlier failure surfaces here
        model = sim.model
        # in double precision, as gsd.hoomd compares it (a box that float32 cannot hold
        # exactly differs from frame 0's and is written in every frame); stored in single
        box = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
        box[: model.dim] = model.box
        points, velocities = sim.backend.frame_arrays()
        threaded = model.n >= self.threaded_from
        if threaded:  # frame_arrays() are only valid until the next step
            if self._buffers is None or self._buffers[0].shape != points.shape:
                self._buffers = np.empty_like(points), np.empty_like(velocities)
            np.copyto(self._buffers[0], points)
            np.copyto(self._buffers[1], velocities)
            points, velocities = self._buffers
        chunks = {
            "configuration/step": np.array([sim.step], dtype=np.uint64),
            "configuration/dimensions": np.array([model.dim], dtype=np.uint8),
            "configuration/box": box,
            "particles/N": np.array([model.n], dtype=np.uint32),
            "particles/position": points,
            "particles/velocity": velocities,
        }
        self._last = sim.step
        flush = threaded or time.monotonic() - self._flushed >= self.flush_interval
        if threaded:
            self._thread = threading.Thread(target=self._write_frame, args=(chunks, flush), name="gsd-writer",
                                            daemon=True)
            self._thread.start()
        else:
            self._write_frame(chunks, flush)
            self._wait()

    def _write_frame(self, chunks: dict[str, np.ndarray], flush: bool) -> None:
        try:
            self._append(chunks)
            if flush and self._dirty:
                self._flush()
        except BaseException as err:  # raised in the caller's thread by _wait()
            self._error = err

    def _flush(self) -> None:
        self._file.flush()
        self._flushed = time.monotonic()
        self._dirty = False

    def _append(self, chunks: dict[str, np.ndarray]) -> None:
        fresh = self._file.nframes == 0
        for name, data in chunks.items():
            if self._differs(name, data):
                self._file.write_chunk(name, data.astype(np.float32) if name == "configuration/box" else data)
        if fresh:
            for name, data in self._static.items():
                self._file.write_chunk(name, data)
            self._file.write_chunk("log/" + PARAMETERS_KEY, self._parameters)
        self._file.end_frame()
        self._dirty = True
        if fresh:
            self._flush()  # frame 0 is read back below, and makes the file a trajectory
            for name, data in chunks.items():
                if self._file.chunk_exists(frame=0, name=name):
                    self._remember(name, self._file.read_chunk(frame=0, name=name) if data.size < _HEAD else data)

    def _wait(self) -> None:
        """Let the frame in flight finish; raise its error, if it failed."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            err, self._error = self._error, None
            raise err

    def sync(self) -> None:
        self._wait()
        if self._dirty and self._file is not None:
            self._flush()

    def close(self) -> None:
        try:
            self.sync()
        finally:
            if self._file is not None:
                self._file.close()
                self._file = None
            self._buffers = None


def static_chunks(model) -> dict[str, np.ndarray]:
    """What frame 0 holds beyond the particles and the parameters, for a model with
    extensions: the species as GSD particle types (``particles/types``, ``particles/typeid``:
    OVITO and freud colour and filter by them), and the walls and obstacles as log entries
    (``flocking/walls``: 1 per axis with walls; ``flocking/obstacles``: one row per
    obstacle, centre in the file's centred coordinates, then radius).

    >>> from flocking import Model
    >>> chunks = static_chunks(Model(n=4, box=8.0, species=[{"n": 1}, {"n": 3, "name": "fast"}],
    ...                              obstacles=[{"centre": [2, 4], "radius": 1}]))
    >>> chunks["particles/typeid"].tolist(), chunks["log/flocking/obstacles"].tolist()
    ([0, 1, 1, 1], [[-2.0, 0.0, 1.0]])
    """
    chunks = {}
    if len(model.species) > 1:
        names = [name.encode() for name in model.species_names]
        width = max(map(len, names)) + 1
        chunks["particles/types"] = np.array(names, dtype=np.dtype((bytes, width))).view(np.int8).reshape(
            len(names), width)
        chunks["particles/typeid"] = np.repeat(np.arange(len(names), dtype=np.uint32), model.species_counts)
    if any(model.walls):
        chunks["log/flocking/walls"] = np.array(model.walls, dtype=np.uint8)
    if model.obstacles:
        box = np.asarray(model.box)
        chunks["log/flocking/obstacles"] = np.array([[*(np.asarray(o.centre) - box / 2), o.radius]
                                                     for o in model.obstacles])
    return chunks


class ObservablesWriter(Writer):
    """A CSV table with a header and one row per step: ``step,polar_order``, then, for a
    model with several species, ``polar_order_<name>`` of each, and for nematic alignment
    ``nematic_order``."""

    def __init__(self, path: str | os.PathLike, mode: str = "w"):
        self.path = os.fspath(path)
        self.mode = mode
        self._file = None
        self.columns = ("step", "polar_order")

    def begin(self, sim) -> None:
        if self._file is None:
            fresh = self.mode == "w" or not os.path.exists(self.path) or os.path.getsize(self.path) == 0
            self._file = open(self.path, self.mode, encoding="utf-8")
            self.mode = "a"  # a later run of the same simulation appends
            extra = sim.extra_observables()
            self.columns = ("step", "polar_order", *extra)
            if fresh:
                self._file.write(",".join(self.columns) + "\n")
                self._file.write(self._rows([sim.step], [sim.polar_order[-1]], extra))
                self._file.flush()

    @staticmethod
    def _rows(steps, phi, extra) -> str:
        columns = [list(steps), list(phi)] + [np.ravel(v).tolist() for v in (extra or {}).values()]
        return "".join(",".join(map(repr, row)) + "\n" for row in zip(*columns))

    def observe(self, steps: np.ndarray, phi: np.ndarray, extra: dict | None = None) -> None:
        # one write of whole lines: a crash never leaves half a row behind a flushed one
        self._file.write(self._rows(steps.tolist(), phi.tolist(), extra))
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
