"""The default backend: numba kernels over cell lists, multi-threaded and deterministic.

Layout. The particle arrays are *structure of arrays*, ``pos[a, slot]`` and
``head[a, slot]``, kept in *cell order* (:mod:`flocking.backends.cells`): after every step
a stable, parallel counting sort by cell scatters them into the other half of a double
buffer, so the particles of one cell, and of a row of cells, are contiguous. ``ids[slot]``
(int32) is the particle behind a slot; it keys the random numbers and the delay ring and
gives the user the id order back. Constant speeds are stored as one number, not an array.

The step itself is :mod:`flocking.backends.cpu_kernels`, built for what the model switches
on (:func:`flocking.backends.features.features`): ``lines`` for metric neighbours on a
grid of at least three cells per axis, ``search`` for topological neighbours and smaller
grids (:func:`kernel_name`).

Determinism. Work is split into fixed units that threads take from an atomic counter as
they become free (which balances clustered states and busy machines). A particle's new
heading depends only on the sorted arrays and on counter-based random numbers, and the sort
is stable: within a cell, particles keep the order they had the step before (id order when
a run starts), whatever the number of threads. A checkpoint saves that order
(:meth:`CPUBackend.memory`), so a run continued from it adds neighbours in the same order as
one that never stopped. No result depends on the number of threads.

Delay. The sum of the neighbours' headings (without the particle itself) and ``1 +`` their
count at step ``t`` (with cohesion, also its pull and push) is exactly what step
``t + tau`` needs: ``_ring[t % tau, id]`` holds it, indexed by particle id, and replaces a
second neighbour search.

>>> from flocking import Model, State
>>> from flocking.backends.cpu import CPUBackend
>>> model = Model(n=200, box=10.0, noise=0.5, seed=2)
>>> backend = CPUBackend(model, State.random(model))
>>> phi = backend.advance(5)
>>> backend.state.step, phi.shape
(5, (5,))
"""

from __future__ import annotations

import math
import os

# Idle OpenMP threads spin only briefly (about a microsecond), then sleep: long enough to
# bridge the back-to-back parallel loops of a step (waking a sleeping thread costs tens of
# microseconds, which halved throughput at N = 1e4), short enough not to take a busy
# machine's cores from other work (long spins halved throughput there; see
# docs/performance.md). Set either variable to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

import numba  # noqa: E402
import numpy as np  # noqa: E402

from ..model import Model, ParameterError  # noqa: E402
from ..observables import heading_total, moment_width  # noqa: E402
from ..state import State  # noqa: E402
from . import cells, cpu_cost, cpu_kernels, frames  # noqa: E402
from .features import features, ring_width, step, tables  # noqa: E402


def kernel_name(model: Model) -> str:
    """Which kernel of :mod:`flocking.backends.cpu_kernels` steps ``model``: ``lines``
    (metric neighbours, at least three cells a side) or ``search`` (topological
    neighbours, or a box under ``3R`` along some axis).

    >>> kernel_name(Model(n=100, box=10.0)), kernel_name(Model(n=100, box=2.5))
    ('lines', 'search')
    >>> kernel_name(Model(n=100, box=10.0, neighbours="topological"))
    'search'
    >>> kernel_name(Model(n=100, box=10.0, neighbours="voronoi"))  # flocking.backends.cpu_graph
    'graph'
    """
    if model.neighbours == "voronoi":
        return "graph"
    if model.neighbours == "metric" and np.all(cells.cell_grid(model) >= 3):
        return "lines"
    return "search"


class CPUBackend:
    """Cell lists and numba threads; bitwise reproducible for any ``NUMBA_NUM_THREADS``."""

    name = "cpu"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Peak memory of a run: the sorted arrays (double-buffered; a written frame lives
        in the spare half), ids, cells, speeds, the delay ring and the sums that prime it,
        the histograms, and the id-ordered ``state`` copy a checkpoint takes (measured:
        82 bytes a particle in 2D; a run writing a trajectory adds the writer's copy of a
        frame, 24, for 107 in all)."""
        d = model.dim
        delay = 8 * (model.delay + 1) * ring_width(d, features(model)) + 4 if model.delay else 0
        speeds = 24 if model.speeds == "uniform" else 0
        per_particle = 32 * d + 12 + speeds + delay + 16 * d + 8
        return model.n * per_particle + 4 * (numba.get_num_threads() + 1) * int(np.prod(cells.cell_grid(model)))

    @staticmethod
    def step_cost(model: Model, positions: np.ndarray) -> tuple[float, float]:
        """Estimated seconds of one core for one step of ``model`` from ``positions``
        (N, d), and the neighbour candidates a particle that the estimate counted
        (:mod:`flocking.backends.cpu_cost`: measured nanoseconds per particle and per
        candidate of the kernel this model gets).

        >>> model = Model(n=4000, density=2.0)
        >>> round(CPUBackend.step_cost(model, np.full((4000, 2), 0.5))[1])  # all in one cell
        4000
        """
        return cpu_cost.step_cost(model, positions, kernel_name(model))

    @staticmethod
    def kernel_kind(model: Model) -> str:
        """The kind of step ``model`` gets, as :data:`flocking.backends.cpu_cost.COSTS`
        prices it (``lines``, ``extended weighted``, ...).

        >>> CPUBackend.kernel_kind(Model(n=100, box=10.0, vision=2.0))
        'extended weighted'
        """
        return cpu_cost.kind(model, kernel_name(model))

    def __init__(self, model: Model, state: State, memory: dict | None = None):
        self.model = model
        n, d = state.n, state.dim
        itype = np.int32 if n < 2**31 - 1 else np.int64
        self._box = np.asarray(model.box, dtype=np.float64)
        self._nc = cells.cell_grid(model)
        self._ncells = int(np.prod(self._nc))
        ctype = np.int32 if self._ncells < 2**31 - 1 else np.int64
        self._start = np.zeros(self._ncells + 1, dtype=itype)
        self._hist = np.zeros((numba.get_num_threads(), self._ncells), dtype=itype)
        self._cell = np.empty(n, dtype=ctype)
        self._pos, self._head = np.empty((d, n)), np.empty((d, n))
        # the other half of the double buffer, allocated when first needed: a state made
        # only to start a simulation is gone by then
        self._spare = None
        self._ids, self._tmp_ids = np.empty(n, dtype=itype), np.empty(n, dtype=itype)
        speeds = state.speeds
        if n and (speeds.strides == (0,) or np.all(speeds == speeds[0])):
            self._spd, self._tmp_spd = speeds[:1].copy(), speeds[:1].copy()  # one number
        else:
            self._spd, self._tmp_spd = np.empty(n), np.empty(n)
        self._step_count = state.step
        self._features = features(model)
        kernel = kernel_name(model)
        if kernel == "graph":  # Voronoi neighbours: a list made each step, then a kernel over it
            from . import cpu_graph

            self._kernel = cpu_graph.kernel(self._features, d, model.box, model.walls)
        else:
            self._kernel = getattr(cpu_kernels.build(cpu_kernels.variant(self._features, kernel), d), kernel)
        units = cells.work_units(self._nc, n, 0 if kernel == "lines" else 1)
        self._partial = np.zeros((units, moment_width(model) if model.extended else 3))
        self._params = step(model)
        self._tables = tables(model)
        self._seed = np.uint64(model.seed)  # its own argument: a double would round seeds above 2**53
        # ring[t % delay, id]: the neighbours' sums at step t (cpu_kernels.remember)
        width = ring_width(d, self._features)
        self._ring = np.zeros((max(model.delay, 1), n if model.delay else 1, width))
        self._load(state, memory)

    def memory(self) -> dict[str, np.ndarray]:
        """What the backend remembers beyond the state: the order of the particles (ids
        slot by slot: within a cell it is the order of earlier steps, which the sums
        follow) and the delay ring, indexed by id."""
        memory = {"order": self._ids.copy()}
        if self.model.delay:
            memory["ring"] = self._ring.copy()
        return memory

    def _load(self, state: State, memory: dict | None) -> None:
        memory = memory or {}
        n = state.n
        order = memory.get("order")
        if order is not None:
            order = np.asarray(order)
            if order.shape != (n,) or order.dtype.kind not in "iu" or not np.array_equal(np.sort(order), np.arange(n)):
                raise ParameterError("resume: the checkpoint's particle order is not a permutation of the particles")
            order = order.astype(self._ids.dtype)
            # in the saved order; the stable sort below then keeps it exactly
            pos, head = state.positions[order].T, state.headings[order].T
            spd = state.speeds[order] if self._spd.shape[0] > 1 else self._tmp_spd
        else:
            order = np.arange(n, dtype=self._ids.dtype)
            # the kernels read the (N, d) arrays through transposed views: no copies
            pos, head = state.positions.T, state.headings.T
            spd = np.ascontiguousarray(state.speeds) if self._spd.shape[0] > 1 else self._tmp_spd
        cells.cell_indices(pos, self._nc, self._nc / self._box, self._cell)
        self._sort_into(pos, head, spd, order, self._spd, self._ids)
        if "ring" in memory:
            self._ring[:] = memory["ring"]
        elif self.model.delay:
            self._prime_delay()

    def _sort_into(self, pos, head, spd, ids, spd2, ids2) -> None:
        """Sort by ``self._cell`` into ``self._pos``, ``self._head``, ``spd2`` and ``ids2``."""
        hist = self._hist[: max(1, min(numba.get_num_threads(), self._hist.shape[0]))]
        cells.sort_cells(self._cell, hist, self._start)
        cells.scatter_sorted(self._cell, hist, pos, head, spd, ids, self._pos, self._head, spd2, ids2)

    def _scratch(self) -> tuple[np.ndarray, np.ndarray]:
        """The spare half of the double buffer ``(new_pos, new_head)``: written by a step,
        free between steps."""
        if self._spare is None:
            self._spare = np.empty_like(self._pos), np.empty_like(self._head)
        return self._spare

    def _prime_delay(self) -> None:
        """Fill every ring slot with the current sums: the initial state stands in for the past."""
        self._ring[:] = self.neighbour_sums()[None]

    def neighbour_sums(self) -> np.ndarray:
        """Per particle id, the sums a delayed step remembers (:func:`cpu_kernels.remember`:
        the neighbours' heading sum, the particle itself left out, and ``1 +`` their count;
        with cohesion, the pull, the push and the core count) for the current state."""
        n = self._pos.shape[1]
        ring = np.zeros((1, n, self._ring.shape[2]))
        params = self._params._replace(delay=1)  # the sums into a one-slot ring; the step is thrown away
        self._kernel(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
                     *self._scratch(), self._cell.copy(), ring, 0,
                     self._step_count, self._seed, params, self._partial.copy(), numba.get_num_threads(),
                     self._tables)
        return ring[0]

    @property
    def step(self) -> int:
        return self._step_count

    @property
    def state(self) -> State:
        d, n = self._pos.shape
        pos, head = np.empty((n, d)), np.empty((n, d))
        pos[self._ids], head[self._ids] = self._pos.T, self._head.T
        if self._spd.shape[0] == n and n > 1:
            spd = np.empty(n)
            spd[self._ids] = self._spd
        else:
            spd = np.broadcast_to(self._spd[0] if n else 0.0, (n,))
        return State(pos, head, spd, self._step_count)

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities as GSD frames hold them: float32 ``(N, 3)`` in
        particle-id order, z = 0 in 2D (what :func:`flocking.state.frame_arrays` gives).

        They live in the spare half of the double buffer (``2 x d x N`` doubles, room for
        both), so a frame costs no memory; they are valid until the next :meth:`advance`.
        """
        n = self._pos.shape[1]
        new_pos, new_head = self._scratch()
        points = new_pos.reshape(-1).view(np.float32)[: 3 * n].reshape(n, 3)
        velocities = new_head.reshape(-1).view(np.float32)[: 3 * n].reshape(n, 3)
        frames.write_frame(self._pos, self._head, self._spd, self._ids, self._box, points, velocities)
        return points, velocities

    def fields(self, grid) -> np.ndarray:
        """The sums ``(species, channel, bin)`` of :class:`flocking.fields.Grid` ``grid``: one
        compiled pass over the slots (:mod:`flocking.backends.field_kernels`), no copy."""
        from .field_kernels import cpu_fields

        return cpu_fields(grid, self._pos, self._head, self._ids)

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (and keep the moment
        sums of each step in :attr:`moments`)."""
        d, n = self._pos.shape
        phi = np.empty(steps)
        self.moments = moments = np.empty((steps, moment_width(self.model)))
        delay, species = self.model.delay, len(self.model.species_counts)
        new_pos, new_head = self._scratch()
        for t in range(steps):
            slot = self._step_count % delay if delay else 0
            self._kernel(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
                         new_pos, new_head, self._cell, self._ring, slot, self._step_count,
                         self._seed, self._params, self._partial, numba.get_num_threads(), self._tables)
            self._sort_into(new_pos, new_head, self._spd, self._ids, self._tmp_spd, self._tmp_ids)
            self._spd, self._tmp_spd = self._tmp_spd, self._spd
            self._ids, self._tmp_ids = self._tmp_ids, self._ids
            self._step_count += 1
            if self.model.extended:
                moments[t] = self._partial.sum(axis=0)
                total = heading_total(moments[t], d, species)
            else:
                total = self._partial.sum(axis=0) if n else np.zeros(3)
                moments[t] = total[:d]
            phi[t] = math.sqrt(float(total @ total)) / max(n, 1)
        return phi
