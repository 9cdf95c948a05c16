"""The GPU backend: cell lists on an NVIDIA GPU (numba-cuda), for one system or an ensemble.

Everything lives on the device between steps: positions and headings as ``(d, M)``
arrays (one coalesced row per axis), particle ids, per-particle speeds where they differ,
the cell starts, the delay ring, the step number. :class:`Engine` advances ``R``
replicas of one size at once (``M = R N`` particles; replica ``r`` owns slots
``[r N, (r + 1) N)`` and cells ``[r C, (r + 1) C)``); :class:`CUDABackend` is its
one-replica case, and :class:`flocking.Ensemble` the public face of the others.

A step is a fixed sequence of launches (see :mod:`flocking.backends.cuda_kernels`):
the step kernel, the digit histogram, one scatter per radix pass (3 for up to 2**24
cells), the gather, the per-replica reduction. Their arguments never change, so on a GPU
whose numba-cuda can capture launches (``cuda.core`` graphs, numba-cuda 0.30 has them)
the sequence is captured once as a CUDA graph and replayed: one host call a step.
Nothing crosses to the host until a block of up to :attr:`Engine.rows` steps is done;
then one copy brings back their polar order.

Same numbers as the other backends. The kernels transcribe :mod:`flocking.backends.kernels`
and draw :mod:`flocking.rng`'s counter-based numbers with the same uint64 arithmetic, so
in float64 one step matches a reference step to rounding. ``precision="float32"`` keeps
positions, headings and all per-particle arithmetic in float32 (a GPU's fast path; the
random numbers are the same, the polar order is summed in float64).

Determinism. After every step particles are sorted by (cell, id), a pure function of
the state: a backend built from a state takes exactly the steps of one that reached that
state by running (so a checkpoint needs only the delay ring), and a replica of an
ensemble gives bit for bit what the same model alone gives. Neighbour sums follow that
order and the polar order is reduced in fixed blocks of each replica.

Cells are those of the CPU backend (:func:`flocking.backends.cpu.cell_grid`): at least
``R`` wide, at most about one per particle, with no capacity per cell: a band or a
single cell may hold any number of particles, and the sort costs the same.

Without a GPU (or numba's CUDA simulator, ``NUMBA_ENABLE_CUDASIM=1``) the constructor
raises :class:`flocking.ParameterError` with one line that says so.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from ..model import Model, ParameterError
from ..state import State, frame_arrays
from .cpu import cell_grid

PRECISIONS = ("float64", "float32")

#: (threads per block, radix bits a pass, sort items a thread) on a GPU and under the
#: simulator (one Python thread per GPU thread: small blocks keep it quick)
_GPU_SHAPE, _SIM_SHAPE = (256, 8, 8), (16, 4, 4)

#: parameters every replica of an ensemble shares (they fix the cells and the arrays)
SHARED = ("dim", "n", "box", "radius", "neighbours", "k", "noise_type", "update", "dt")
#: parameters a replica may have of its own
PER_REPLICA = ("seed", "noise", "alignment", "speed", "speeds", "delay")

#: most replicas of one engine (blocks of one replica's reduction are a grid dimension)
MAX_REPLICAS = 2**20


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


def _simulated() -> bool:
    from numba.core import config

    return bool(config.ENABLE_CUDASIM)


def ensemble_key(model: Model) -> tuple:
    """What replicas of one ensemble must share: models with equal keys can run together.

    >>> a = Model(n=100, box=10.0, noise=0.5, seed=1)
    >>> ensemble_key(a) == ensemble_key(a.replace(noise=2.0, seed=7, delay=3))
    True
    >>> ensemble_key(a) == ensemble_key(a.replace(radius=1.5))
    False
    """
    return tuple(getattr(model, name) for name in SHARED)


class Engine:
    """``R`` replicas of one size, advanced together on one GPU.

    ``models`` share :data:`SHARED` and may differ in :data:`PER_REPLICA`; ``states`` (one
    per model, all at the same step) and ``memories`` (what :meth:`memory` gave, or
    ``None``) are loaded as given; ``graphs=False`` launches every kernel from the host
    instead of replaying a captured CUDA graph (the results are the same).
    """

    def __init__(self, models: Sequence[Model], states: Sequence[State],
                 memories: Sequence[dict | None] | None = None, precision: str = "float64",
                 graphs: bool = True):
        if precision not in PRECISIONS:
            raise ParameterError(f"precision: must be 'float64' or 'float32' (got {precision!r})")
        models, states = list(models), list(states)
        check_models(models)
        if len(states) != len(models):
            raise ParameterError(f"states: one per model ({len(models)}; got {len(states)})")
        model = models[0]
        n, d, r = model.n, model.dim, len(models)
        for s in states:
            if s.n != n or s.dim != d:
                raise ParameterError(f"states: each must hold {n} particles in {d}D, as the models")
        if len({s.step for s in states}) != 1:
            raise ParameterError("states: replicas advance together, so they must all be at the same step")
        check_supported(models)
        if r * n >= 2**31:
            raise ParameterError(f"n: the cuda backend takes fewer than 2**31 particles in all (got {r} x {n})")
        cuda = _cuda()
        from .cuda_kernels import GEOM, INTS, build, passes

        self._cuda = cuda
        self.models = tuple(models)
        self.precision = precision
        self.replicas, self.n, self.dim = r, n, d
        simulated = _simulated()
        if simulated:
            # the simulator runs the uint64 hash in NumPy scalars, which warn on the
            # (intended) wrap-around of the multiplications
            warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning,
                                    "flocking.backends.cuda_kernels")
        block, bits, items = _SIM_SHAPE if simulated else _GPU_SHAPE
        k = model.k if model.neighbours == "topological" else 0
        self._k = kernels = build(precision, d, k, block, bits, items)
        real = kernels.real
        self._real = real

        box = np.asarray(model.box, dtype=np.float64)
        nc = cell_grid(model)
        cells = int(np.prod(nc))
        nc3 = [int(x) for x in nc] + [1] * (3 - d)
        box3 = list(box) + [1.0] * (3 - d)
        geom = dict(inv0=nc3[0] / box3[0], inv1=nc3[1] / box3[1], inv2=nc3[2] / box3[2],
                    l0=box3[0], l1=box3[1], l2=box3[2], r2=model.radius**2,
                    width=float(np.min(box / nc)), dt=model.dt)
        m = r * n
        per_particle = any(s.n and not np.all(s.speeds == s.speeds[0]) for s in states)
        self._rows = max(1, min(1024, 2**22 // max(1, r * d)))
        ints = dict(nc0=nc3[0], nc1=nc3[1], nc2=nc3[2], n=n, cells=cells, replicas=r,
                    vectorial=int(model.noise_type == "vectorial"), backward=int(model.update == "backward"),
                    speeds=int(per_particle), rows=self._rows)
        # the values are converted to `real` one by one, exactly as the kernels' constants
        self._geom = cuda.to_device(np.array([real(geom[name]) for name in GEOM], dtype=real))
        self._ints = cuda.to_device(np.array([ints[name] for name in INTS], dtype=np.int64))
        self._rp = cuda.to_device(np.array([[real(x.noise), real(x.alignment), real(x.speed)] for x in models],
                                           dtype=real))
        self._rtau = cuda.to_device(np.array([x.delay for x in models], dtype=np.int64))
        self._rseed = cuda.to_device(np.array([x.seed for x in models], dtype=np.uint64))
        self._per_particle = per_particle
        self._cells = cells

        self._block, self._qb = block, -(-n // block)
        self._passes = passes(max(1, (r * cells - 1).bit_length()), bits)
        dev = cuda.device_array
        self._pos, self._head = dev((d, m), real), dev((d, m), real)
        self._new_pos, self._new_head = dev((d, m), real), dev((d, m), real)
        self._ids, self._new_ids = dev(m, np.int32), dev(m, np.int32)
        size = m if per_particle else 1
        self._spd, self._new_spd = dev(size, real), dev(size, real)
        self._rec, self._rec2 = dev(m, np.uint64), dev(m, np.uint64)
        start = np.zeros(r * cells + 1, dtype=np.int32)
        start[-1] = m
        self._start = cuda.to_device(start)
        self._partial = dev((d, r * self._qb), np.float64)
        self._phi = cuda.to_device(np.zeros((r, self._rows, d)))
        self._clock = cuda.to_device(np.array([states[0].step, 1], dtype=np.int64))
        self._hist = cuda.to_device(np.zeros(kernels.max_passes * kernels.digits_per_pass, dtype=np.int32))
        self._tile_counter = cuda.to_device(np.zeros(kernels.max_passes, dtype=np.int32))
        self._status = cuda.to_device(np.zeros(-(-m // kernels.tile) * kernels.digits_per_pass, dtype=np.int64))
        self._taus = [x.delay for x in models]
        self._ring = cuda.to_device(np.zeros((m, max(self._taus), 4) if max(self._taus) else (1, 1, 4), dtype=real))
        self._step_count = states[0].step
        self._graphs = graphs and not simulated
        self._graph = None
        self._load(states, memories or [None] * r)

    # -- device plumbing -------------------------------------------------------------

    def _load(self, states: list[State], memories: Sequence[dict | None]) -> None:
        """Upload the states (id order) into the ``new_*`` buffers, then sort them in."""
        real, n, d = self._real, self.n, self.dim
        box = np.asarray(self.models[0].box)
        pos, head = np.empty((d, self.replicas * n), real), np.empty((d, self.replicas * n), real)
        for r, s in enumerate(states):
            p = s.positions.astype(real)
            p = np.where(p >= box.astype(real), p - box.astype(real), p)  # rounding may reach L
            pos[:, r * n:(r + 1) * n] = p.T
            head[:, r * n:(r + 1) * n] = s.headings.T
        self._new_pos.copy_to_device(pos)
        self._new_head.copy_to_device(head)
        self._new_ids.copy_to_device(np.tile(np.arange(n, dtype=np.int32), self.replicas))
        if self._per_particle:
            self._new_spd.copy_to_device(np.concatenate([s.speeds for s in states]).astype(real))
        k = self._k
        k.cells[self.replicas * self._qb, self._block](self._new_pos, self._geom, self._ints, self._rec)
        self._sort(tick=False)
        if max(self._taus):
            self._load_ring(memories)

    def _load_ring(self, memories: Sequence[dict | None]) -> None:
        """The delay ring: from each replica's memory, or primed with today's sums."""
        n, d = self.n, self.dim
        given = [m.get("ring") if m else None for m in memories]
        if any(ring is None and tau for ring, tau in zip(given, self._taus)):
            self._launch_step(prime=True)
        if not any(ring is not None for ring in given):
            return
        ring = self._ring.copy_to_host()
        for r, (saved, tau) in enumerate(zip(given, self._taus)):
            if saved is None or not tau:
                continue
            saved = np.asarray(saved, dtype=np.float64)
            if saved.shape != (tau, n, d + 1):
                raise ParameterError(f"resume: the saved delay ring has shape {saved.shape}, "
                                     f"not (delay, n, dim + 1) = {(tau, n, d + 1)}")
            block = ring[r * n:(r + 1) * n, :tau]
            block[..., :d] = saved[..., :d].transpose(1, 0, 2)
            block[..., 3] = saved[..., d].T
        self._ring.copy_to_device(ring)

    def _launch_step(self, prime: bool = False, stream=0) -> None:
        k = self._k
        k.step[self.replicas * self._qb, self._block, stream](
            self._pos, self._head, self._spd, self._ids, self._start, self._geom, self._ints,
            self._rp, self._rtau, self._rseed, self._clock, self._ring, prime,
            self._new_pos, self._new_head, self._new_ids, self._new_spd, self._rec)
        if not prime:
            self._sort(tick=True, stream=stream)

    def _sort(self, tick: bool, stream=0) -> None:
        """Sort ``rec`` (id order) by cell into the live arrays; cell starts; with
        ``tick``, the step counter moves on and the polar order goes into its row."""
        k, block = self._k, self._block
        src = _radix(k, self._rec, self._rec2, self.replicas * self.n, self._passes, self._hist, self._status,
                     self._tile_counter, self._clock, tick, stream)
        k.gather[self.replicas * self._qb, block, stream](
            src, self._new_pos, self._new_head, self._new_ids, self._new_spd, self._ints,
            self._pos, self._head, self._ids, self._spd, self._start, self._partial)
        k.finish[self.replicas, block, stream](self._partial, self._ints, self._phi, self._clock, self._hist,
                                               self._tile_counter, tick)

    def _capture(self):
        """The launches of one step as a CUDA graph, or None where numba-cuda cannot
        capture (before its ``cuda.core`` graphs) or the capture fails; the kernels are
        compiled by then (a step was taken)."""
        try:
            from cuda.core import Device, Stream

            device = Device()
            device.set_current()
            builder = device.create_graph_builder()
            builder.begin_building()
            self._launch_step(stream=builder)
            graph = builder.end_building().complete()
            return graph, Stream.from_handle(0)
        except Exception:  # noqa: BLE001 - any failure: launch from the host instead
            self._graphs = False
            return None

    # -- public surface --------------------------------------------------------------

    @property
    def step(self) -> int:
        return self._step_count

    @property
    def rows(self) -> int:
        """Steps whose polar order the device holds before it must be copied back."""
        return self._rows

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; the polar order of every replica after each, ``(R, steps)``."""
        steps = int(steps)
        out = np.empty((self.replicas, steps))
        done = 0
        while done < steps:
            chunk = min(self._rows, steps - done)
            for _ in range(chunk):
                if self._graph is not None:
                    graph, stream = self._graph
                    graph.launch(stream)
                else:
                    self._launch_step()
                    if self._graphs:
                        self._graph = self._capture()
            rows = (self._step_count + 1 + np.arange(chunk)) % self._rows
            sums = self._phi.copy_to_host()[:, rows]
            out[:, done:done + chunk] = np.sqrt(np.sum(sums * sums, axis=2)) / self.n
            self._step_count += chunk
            done += chunk
        return out

    def states(self) -> list[State]:
        """Copies in particle-id order, float64 (float32 headings renormalised)."""
        n, d = self.n, self.dim
        ids = self._ids.copy_to_host()
        pos_all, head_all = self._pos.copy_to_host(), self._head.copy_to_host()
        spd_all = self._spd.copy_to_host() if self._per_particle else None
        box = np.asarray(self.models[0].box)
        out = []
        for r, model in enumerate(self.models):
            lo, hi = r * n, (r + 1) * n
            pid = ids[lo:hi]
            pos, head = np.empty((n, d)), np.empty((n, d))
            pos[pid] = pos_all[:, lo:hi].T
            head[pid] = head_all[:, lo:hi].T
            if spd_all is not None:
                spd = np.empty(n)
                spd[pid] = spd_all[lo:hi]
            else:
                spd = np.broadcast_to(np.float64(self._real(model.speed)), (n,))
            if self.precision != "float64":
                head /= np.linalg.norm(head, axis=1, keepdims=True)
                pos = np.where(pos >= box, pos - box, pos)  # float32(L) may exceed L: fold back
            out.append(State(pos, head, spd, self._step_count))
        return out

    def memory(self) -> list[dict[str, np.ndarray]]:
        """Per replica, the delay ring in the cpu backend's layout ``(delay, N, d + 1)``,
        indexed by id (``{}`` without a delay)."""
        n, d = self.n, self.dim
        if not max(self._taus):
            return [{} for _ in self.models]
        ring = self._ring.copy_to_host().astype(np.float64)
        out = []
        for r, tau in enumerate(self._taus):
            if not tau:
                out.append({})
                continue
            block = ring[r * n:(r + 1) * n, :tau]  # (N, tau, 4)
            saved = np.empty((tau, n, d + 1))
            saved[..., :d] = block[..., :d].transpose(1, 0, 2)
            saved[..., d] = block[..., 3].T
            out.append({"ring": saved})
        return out


def _radix(k, rec, rec2, m: int, npass: int, hist, status, tiles, clock, tick: bool, stream=0):
    """Sort ``rec[:m]`` by the upper 32 bits (``npass`` radix passes, ``rec2`` the other
    buffer); the buffer that holds the result."""
    grid = -(-m // k.tile)
    k.digits[grid, k.block, stream](rec, hist, m, npass, clock, tick)
    src, dst = rec, rec2
    for p in range(npass):
        k.scatter[grid, k.block, stream](src, dst, m, p, hist, status, tiles, clock)
        src, dst = dst, src
    return src


def radix_sort(records: np.ndarray, key_bits: int = 31, shape: tuple[int, int, int] | None = None) -> np.ndarray:
    """``records`` (uint64) sorted stably by their upper 32 bits, which must be below
    ``2**key_bits``, by the device's radix sort (the sort of every step, on its own).

    ``shape`` is (threads per block, bits a pass, items a thread); by default the one
    the backend uses on this device (or under the simulator).
    """
    cuda = _cuda()
    from .cuda_kernels import build, passes

    block, bits, items = shape or (_SIM_SHAPE if _simulated() else _GPU_SHAPE)
    k = build("float64", 2, 0, block, bits, items)
    records = np.ascontiguousarray(records, dtype=np.uint64)
    m = len(records)
    if m == 0:
        return records.copy()
    rec, rec2 = cuda.to_device(records), cuda.device_array(m, np.uint64)
    hist = cuda.to_device(np.zeros(k.max_passes * k.digits_per_pass, dtype=np.int32))
    tiles = cuda.to_device(np.zeros(k.max_passes, dtype=np.int32))
    status = cuda.to_device(np.zeros(-(-m // k.tile) * k.digits_per_pass, dtype=np.int64))
    clock = cuda.to_device(np.array([0, 1], dtype=np.int64))
    return _radix(k, rec, rec2, m, passes(key_bits, bits), hist, status, tiles, clock, False).copy_to_host()


def check_supported(models: Sequence[Model]) -> None:
    """Refuse, in one line naming them, models this backend does not run yet: those with
    extensions (:attr:`flocking.Model.extensions`)."""
    on = [name for m in models for name in m.extensions]
    if on:
        names = ", ".join(dict.fromkeys(on))
        raise ParameterError(f"backend: 'cuda' does not run the extensions yet (this model has {names}): use 'cpu'")


def check_models(models: Sequence[Model]) -> None:
    """Refuse an empty list, or models that cannot share one ensemble (see :data:`SHARED`)."""
    if not models:
        raise ParameterError("models: give at least one model")
    if len(models) > MAX_REPLICAS:
        raise ParameterError(f"models: at most {MAX_REPLICAS} replicas in one ensemble (got {len(models)})")
    first = models[0]
    for i, model in enumerate(models[1:], 1):
        for name in SHARED:
            if getattr(model, name) != getattr(first, name):
                raise ParameterError(f"models: every replica must have the same {name} "
                                     f"(model 0 has {getattr(first, name)!r}, model {i} {getattr(model, name)!r})")


class CUDABackend:
    """Cell lists on an NVIDIA GPU, one thread per particle; ``precision`` is
    ``"float64"`` (default) or ``"float32"``; ``graphs=False`` launches every kernel
    from the host (see :class:`Engine`)."""

    name = "cuda"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Host memory of a run (the device holds the rest): the id-ordered copies of the state."""
        return model.n * (2 * model.dim + 1) * 8 * 3

    def __init__(self, model: Model, state: State, memory: dict | None = None, precision: str = "float64",
                 graphs: bool = True):
        if precision not in PRECISIONS:
            raise ParameterError(f"precision: must be 'float64' or 'float32' (got {precision!r})")
        self.model = model
        self.precision = precision
        self._engine = Engine([model], [state], [memory], precision=precision, graphs=graphs)

    @property
    def step(self) -> int:
        return self._engine.step

    @property
    def state(self) -> State:
        """A copy in particle-id order, float64 (float32 headings renormalised)."""
        return self._engine.states()[0]

    def memory(self) -> dict[str, np.ndarray]:
        """The delay ring in the cpu backend's layout ``(delay, N, d + 1)``, indexed by id."""
        return self._engine.memory()[0]

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities, float32 ``(N, 3)`` in id order (a GSD frame's)."""
        return frame_arrays(self.state, self.model.box)

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (one copy per
        :attr:`Engine.rows` steps)."""
        return self._engine.advance(steps)[0]
