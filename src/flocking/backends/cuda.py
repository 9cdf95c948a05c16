"""The GPU backend: the CPU backend's cell-list design on an NVIDIA GPU (numba-cuda).

Everything lives on the device between steps: positions and headings as ``(d, N)``
arrays (one coalesced row per axis), speeds and particle ids, all kept in cell order by a
stable counting sort rebuilt every step; the cell starts; the delay ring. A step is a
fixed sequence of kernels (see :mod:`flocking.backends.cuda_kernels`) with no host
round trip; the heading sum of every step is reduced on the device into a table that
:meth:`CUDABackend.advance` copies back once, at its end. The state crosses to the host
only when :attr:`CUDABackend.state` is read.

Same numbers as the other backends. The kernels transcribe :mod:`flocking.backends.kernels`
and draw :mod:`flocking.rng`'s counter-based numbers with the same uint64 arithmetic, so
in float64 one step matches a reference step to rounding. ``precision="float32"`` keeps
positions, headings and all per-particle arithmetic in float32 (a GPU's fast path; the
random numbers are the same, the polar order is summed in float64).

Determinism. The order of particles after the sort is unique (the sort is stable), the
neighbour sums are taken in that order and the polar order is reduced in fixed blocks:
a run does not depend on thread scheduling, and the same seed gives the same run.

Cells are those of the CPU backend (:func:`flocking.backends.cpu.cell_grid`): at least
``R`` wide, at most about one per particle, with no capacity per cell: a band or a
single cell may hold any number of particles.

Without a GPU (or numba's CUDA simulator, ``NUMBA_ENABLE_CUDASIM=1``) the constructor
raises :class:`flocking.ParameterError` with one line that says so.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..model import Model, ParameterError
from ..state import State, frame_arrays
from .cpu import cell_grid

PRECISIONS = ("float64", "float32")

#: Threads per block on a GPU, and under the simulator (one Python thread each).
_BLOCK, _SIM_BLOCK = 256, 16


def _cuda():
    """numba.cuda, once it is known to have a device (or the simulator)."""
    hint = "backend: 'cuda' needs an NVIDIA GPU with numba-cuda (pip install 'flocking[cuda]'"
    try:
        from numba import cuda
    except ImportError as err:  # pragma: no cover - numba ships numba.cuda or numba-cuda does
        raise ParameterError(f"{hint}; {err})") from None
    try:
        available = cuda.is_available()
    except Exception as err:  # noqa: BLE001 - a broken driver or toolkit: say why, in one line
        raise ParameterError(f"{hint}; {type(err).__name__}: {err})") from None
    if not available:
        raise ParameterError(f"{hint}; no CUDA device found)")
    return cuda


class CUDABackend:
    """Cell lists on an NVIDIA GPU, one thread per particle; ``precision`` is
    ``"float64"`` (default) or ``"float32"``."""

    name = "cuda"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Host memory of a run (the device holds the rest): the id-ordered copies of the state."""
        return model.n * (2 * model.dim + 1) * 8 * 3

    def __init__(self, model: Model, state: State, memory: dict | None = None, precision: str = "float64"):
        if precision not in PRECISIONS:
            raise ParameterError(f"precision: must be 'float64' or 'float32' (got {precision!r})")
        if model.n >= 2**31:
            raise ParameterError(f"n: the cuda backend takes fewer than 2**31 particles (got {model.n})")
        if model.extended:
            raise ParameterError("backend: 'cuda' does not run the extensions yet (walls, obstacles, species, "
                                 "coupling, vision, nematic alignment, chirality, fields): use 'cpu'")
        cuda = _cuda()
        from .cuda_kernels import build

        self._cuda = cuda
        self.model = model
        self.precision = precision
        n, d = state.n, state.dim
        from numba.core import config

        if config.ENABLE_CUDASIM:
            # the simulator runs the uint64 hash in NumPy scalars, which warn on the
            # (intended) wrap-around of the multiplications
            warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning,
                                    "flocking.backends.cuda_kernels")
        block = _SIM_BLOCK if config.ENABLE_CUDASIM else _BLOCK
        self._block = block
        k = model.k if model.neighbours == "topological" else 0
        self._k = build(precision, d, k, block)
        real = self._k.real
        self._real = real

        box = np.asarray(model.box, dtype=np.float64)
        nc = cell_grid(model)
        self._ncells = int(np.prod(nc))
        nc3 = [int(x) for x in nc] + [1] * (3 - d)
        box3 = list(box) + [1.0] * (3 - d)
        self._geometry = (
            *nc3,
            *(real(nc3[a] / box3[a]) for a in range(3)),
            *(real(x) for x in box3),
        )
        self._params = (
            real(model.radius**2), real(float(np.min(box / nc))), real(model.noise),
            model.noise_type == "vectorial", real(model.alignment),
        )
        self._motion = (real(model.dt), model.update == "backward", np.uint64(model.seed))

        grid = (n + block - 1) // block
        self._grid = grid
        dev = cuda.device_array
        self._pos, self._head = dev((d, n), real), dev((d, n), real)
        self._new_pos, self._new_head = dev((d, n), real), dev((d, n), real)
        self._spd, self._spd2 = dev(n, real), dev(n, real)
        self._ids, self._ids2 = dev(n, np.int32), dev(n, np.int32)
        self._cell, self._order = dev(n, np.int32), dev(n, np.int32)
        self._counts = cuda.to_device(np.zeros(self._ncells, dtype=np.int32))
        start = np.zeros(self._ncells + 1, dtype=np.int32)
        start[-1] = n
        self._start = cuda.to_device(start)
        self._partial = dev((d, grid), np.float64)
        # block totals of each level of the prefix sum
        self._levels = []
        size = self._ncells
        while True:
            blocks = (size + block - 1) // block
            self._levels.append(dev(blocks, np.int32))
            if blocks == 1:
                break
            size = blocks
        delay = model.delay
        self._ring = dev((max(delay, 1), d + 1, n if delay else 1), real)
        self._step_count = state.step
        self._load(state, memory)

    def memory(self) -> dict[str, np.ndarray]:
        """The delay ring in the cpu backend's layout ``(delay, N, d + 1)``, indexed by id."""
        if not self.model.delay:
            return {}
        return {"ring": np.ascontiguousarray(self._ring.copy_to_host().transpose(0, 2, 1), dtype=np.float64)}

    # -- device plumbing -------------------------------------------------------------

    def _load(self, state: State, memory: dict | None = None) -> None:
        """Upload ``state`` (id order) into the unsorted buffers, then sort into cell order."""
        k, cuda, real = self._k, self._cuda, self._real
        box = np.asarray(self.model.box)
        pos = state.positions.astype(real)
        pos = np.where(pos >= box.astype(real), pos - box.astype(real), pos)  # rounding may reach L
        self._new_pos.copy_to_device(np.ascontiguousarray(pos.T))
        self._new_head.copy_to_device(np.ascontiguousarray(state.headings.T.astype(real)))
        self._spd2.copy_to_device(state.speeds.astype(real))
        self._ids2.copy_to_device(np.arange(state.n, dtype=np.int32))
        k.cells[self._grid, self._block](self._new_pos, *self._geometry[:6], self._cell, self._counts)
        phi = cuda.device_array((1, state.dim), np.float64)
        self._sort(self._spd2, self._ids2, phi, 0)
        if memory and "ring" in memory:
            ring = np.ascontiguousarray(np.asarray(memory["ring"]).transpose(0, 2, 1), dtype=self._real)
            self._ring.copy_to_device(ring)
        elif self.model.delay:
            self._prime_delay()

    def _prime_delay(self) -> None:
        """Fill every ring slot with the current sums: the initial state stands in for the past."""
        cuda, n, d = self._cuda, self.model.n, self.model.dim
        # zeros: the priming step reads the slot before writing today's sums into it (and
        # then moves particles with what it read, which is thrown away); garbage there could
        # be NaN, which the CUDA simulator refuses to turn into a cell index
        once = cuda.to_device(np.zeros((1, d + 1, n), self._real))
        scratch = cuda.device_array((d, n), self._real), cuda.device_array((d, n), self._real)
        counts = cuda.to_device(np.zeros(self._ncells, dtype=np.int32))
        self._launch_step(once, 1, 0, scratch[0], scratch[1], cuda.device_array(n, np.int32), counts)
        sums = once.copy_to_host()
        self._ring.copy_to_device(np.ascontiguousarray(np.broadcast_to(sums, self._ring.shape)))

    def _launch_step(self, ring, delay, slot, new_pos, new_head, cell, counts) -> None:
        dt, backward, seed = self._motion
        r2, width, eta, vectorial, epsilon = self._params
        self._k.step[self._grid, self._block](
            self._pos, self._head, self._spd, self._ids, self._start, *self._geometry,
            r2, width, eta, vectorial, epsilon, delay, dt, backward, seed,
            np.uint64(self._step_count), ring, slot, new_pos, new_head, cell, counts)

    def _sort(self, spd, ids, phi, row: int) -> None:
        """Counting sort of ``new_*`` (and ``spd``, ``ids``) by ``cell`` into the live
        arrays; the heading sum into ``phi[row]``."""
        k, block = self._k, self._block
        # exclusive prefix sum of the histogram into start[:-1]
        data, out = self._counts, self._start[:-1]
        for sums in self._levels:
            k.scan[sums.shape[0], block](data, out, sums)
            data = out = sums
        for level in range(len(self._levels) - 2, -1, -1):
            target = self._start[:-1] if level == 0 else self._levels[level - 1]
            k.add[self._levels[level].shape[0], block](target, self._levels[level])
        k.scatter[self._grid, block](self._cell, self._start, self._counts, self._order)
        k.cell_sort[(self._ncells + block - 1) // block, block](self._start, self._order, ids, self._ncells)
        spd_out = self._spd2 if spd is self._spd else self._spd
        ids_out = self._ids2 if ids is self._ids else self._ids
        k.gather[self._grid, block](self._order, self._new_pos, self._new_head, spd, ids,
                                    self._pos, self._head, spd_out, ids_out, self._partial)
        self._spd, self._spd2 = spd_out, spd
        self._ids, self._ids2 = ids_out, ids
        k.reduce[1, block](self._partial, phi, row)

    # -- public surface --------------------------------------------------------------

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities, float32 ``(N, 3)`` in id order (a GSD frame's)."""
        return frame_arrays(self.state, self.model.box)

    @property
    def step(self) -> int:
        return self._step_count

    @property
    def state(self) -> State:
        """A copy in particle-id order, float64 (float32 headings renormalised)."""
        n, d = self.model.n, self.model.dim
        ids = self._ids.copy_to_host()
        pos, head, spd = np.empty((n, d)), np.empty((n, d)), np.empty(n)
        pos[ids] = self._pos.copy_to_host().T
        head[ids] = self._head.copy_to_host().T
        spd[ids] = self._spd.copy_to_host()
        if self.precision != "float64":
            head /= np.linalg.norm(head, axis=1, keepdims=True)
            box = np.asarray(self.model.box)  # float32(L) may exceed L: fold back
            pos = np.where(pos >= box, pos - box, pos)
        return State(pos, head, spd, self._step_count)

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (one copy at the end)."""
        n, d, delay = self.model.n, self.model.dim, self.model.delay
        phi = self._cuda.device_array((max(steps, 1), d), np.float64)
        for t in range(steps):
            slot = self._step_count % delay if delay else 0
            self._launch_step(self._ring, delay, slot, self._new_pos, self._new_head,
                              self._cell, self._counts)
            self._sort(self._spd, self._ids, phi, t)
            self._step_count += 1
        sums = phi.copy_to_host()[:steps]
        return np.sqrt(np.sum(sums * sums, axis=1)) / n
