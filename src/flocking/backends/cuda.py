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

Same numbers as the other backends. The kernels compile :mod:`flocking.rules` (the update,
the pair rule, the geometry, the random numbers) from the text the CPU kernels compile, so
in float64 one step matches a reference step to rounding. ``precision="float32"`` keeps
positions, headings and all per-particle arithmetic in float32 (a GPU's fast path; the
random numbers are the same, the moments are summed in float64).

Determinism. After every step particles are sorted by (cell, id), a pure function of
the state: a backend built from a state takes exactly the steps of one that reached that
state by running (so a checkpoint needs only the delay ring), and a replica of an
ensemble gives bit for bit what the same model alone gives. Neighbour sums follow that
order and the polar order is reduced in fixed blocks of each replica.

Extensions run in kernels compiled for what the model switches on
(:func:`flocking.backends.features.features`, as on the CPU); :attr:`Engine.moments` then
holds each step's per-species and nematic moment sums, from which
:class:`flocking.Simulation` records their observables.

Cells are those of the CPU backend (:func:`flocking.backends.cells.cell_grid`): at least
``R`` wide, at most about one per particle, with no capacity per cell: a band or a
single cell may hold any number of particles, and the sort costs the same.

Without a GPU (or numba's CUDA simulator, ``NUMBA_ENABLE_CUDASIM=1``) the constructor
raises :class:`flocking.ParameterError` with one line that says so.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Sequence

import numpy as np

from ..model import Model, ParameterError
from ..observables import heading_total, moment_width
from ..rules.geometry import image_shift
from ..space import Space
from ..state import State, frame_arrays
from . import cuda_init
from .cells import cell_grid
from .cuda_sort import Launch, radix_launches
from .features import features, ring_width, tables
from .sizes import check_device

PRECISIONS = ("float64", "float32")

#: (threads per block, radix bits a pass, sort items a thread) on a GPU and under the
#: simulator (one Python thread per GPU thread: small blocks keep it quick)
_GPU_SHAPE, _SIM_SHAPE = Launch(256, 8, 8), Launch(16, 4, 4)

#: how often (s) a process running the simulator switches threads (:func:`_steady_simulator`)
SIMULATOR_SWITCH_S = 3e-4

#: parameters every replica of an ensemble shares (they fix the cells, the arrays and the
#: kernels' extensions)
SHARED = ("dim", "n", "box", "radius", "neighbours", "k", "noise_type", "update", "dt",
          "boundary", "obstacles", "species", "coupling", "vision", "alignment_rule", "field", "cohesion",
          "cohesion_radii")
#: parameters a replica may have of its own
PER_REPLICA = ("seed", "noise", "alignment", "speed", "speeds", "delay", "chirality", "field_strength")

#: most moment sums a step (``dim`` per species, then the nematic products) the kernels
#: reduce in shared memory
MAX_WIDTH = 20

#: most replicas of one engine (blocks of one replica's reduction are a grid dimension)
MAX_REPLICAS = 2**20

#: particles copied to the host at a time by :meth:`Engine.states` (float32: 4 MiB an axis)
COPY_CHUNK = 1 << 20


def require_cuda():
    """numba.cuda, once it is known to have a device (or the simulator)."""
    hint = "backend: 'cuda' needs an NVIDIA GPU with numba-cuda (pip install '.[cuda]' in flocking's source " \
           "folder"
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


def _steady_simulator() -> None:
    """Ready numba's CUDA simulator (once a process; the simulator only) for the kernels.

    - The simulator runs the uint64 hash in NumPy scalars, which warn on the (intended)
      wrap-around of the multiplications: those warnings are ignored (the registry a first
      warning would add to a kernel's globals is there from the start,
      :func:`flocking.rules.rebind`: the simulator's threads may be iterating over them).
    - It runs a block's threads as Python threads and finds a call site's shared array by
      a look-up then an insertion in a dict; a thread switched out between the two lets
      another allocate a second array, so under load two threads of a block could see
      different "shared" memory. Here the look-up and the insertion are one locked step.
    - Its scheduler polls the block's threads in a loop that holds the GIL until Python
      switches threads (every 5 ms by default), so each barrier waited for it. Here the
      process switches every 0.3 ms: two simulated steps of 40 particles took 0.7 s
      instead of 2.7 s (0.1 and 0.5 ms: as quick; 0.03 ms: 1.0 to 1.3 s). The setting is
      the process's.
    """
    import threading

    from numba.core import types
    from numba.cuda.simulator import kernelapi
    from numba.np import numpy_support

    warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning, "flocking.rng")
    sys.setswitchinterval(SIMULATOR_SWITCH_S)
    shared = kernelapi.FakeCUDAShared
    if getattr(shared.array, "serialised", False):
        return
    lock, allocate = threading.Lock(), shared.array

    def array(self, shape, dtype):
        if shape == 0:  # dynamic shared memory: one buffer, no look-up
            return allocate(self, shape, dtype)
        caller = sys._getframe(1)
        key = (caller.f_code.co_filename, caller.f_lineno)  # the call site, as the simulator's
        with lock:
            found = self._allocations.get(key)
            if found is None:
                kind = numpy_support.as_dtype(dtype) if isinstance(dtype, types.Type) else dtype
                found = self._allocations[key] = np.empty(shape, kind)
        return found

    array.serialised = True
    shared.array = array


def ensemble_key(model: Model) -> tuple:
    """What replicas of one ensemble must share: models with equal keys can run together.

    >>> a = Model(n=100, box=10.0, noise=0.5, seed=1)
    >>> ensemble_key(a) == ensemble_key(a.replace(noise=2.0, seed=7, delay=3))
    True
    >>> ensemble_key(a) == ensemble_key(a.replace(radius=1.5))
    False
    >>> ensemble_key(a) == ensemble_key(a.replace(chirality=0.1))  # plain and extended kernels
    False
    """
    return tuple(getattr(model, name) for name in SHARED) + (model.extended,)


class Engine:
    """``R`` replicas of one size, advanced together on one GPU.

    ``models`` share :data:`SHARED` and may differ in :data:`PER_REPLICA`; ``states`` (one
    per model, all at the same step) and ``memories`` (what :meth:`memory` gave, or
    ``None``) are loaded as given; ``graphs=False`` launches every kernel from the host
    instead of replaying a captured CUDA graph (the results are the same). After
    :meth:`advance`, ``moments`` holds every replica's moment sums of those steps.
    """

    def __init__(self, models: Sequence[Model], states: Sequence[State],
                 memories: Sequence[dict | None] | None = None, precision: str = "float64",
                 graphs: bool = True):
        if precision not in PRECISIONS:
            raise ParameterError(f"precision: must be 'float64' or 'float32' (got {precision!r})")
        models = list(models)
        check_models(models)
        check_device(models, precision)  # before any state is drawn on the host
        states, kinds = device_states(models, states)
        model = models[0]
        n, d, r = model.n, model.dim, len(models)
        for s in states:
            if s.n != n or s.dim != d:
                raise ParameterError(f"states: each must hold {n} particles in {d}D, as the models")
        if len({s.step for s in states}) > 1:
            raise ParameterError("states: replicas advance together, so they must all be at the same step")
        check_supported(models)
        if r * n >= 2**31:
            raise ParameterError(f"n: the cuda backend takes fewer than 2**31 particles in all (got {r} x {n})")
        cuda = require_cuda()
        from . import cuda_kernels
        from .cuda_sort import passes

        self._cuda = cuda
        self.models = tuple(models)
        self.precision = precision
        self.replicas, self.n, self.dim = r, n, d
        simulated = _simulated()
        if simulated:
            _steady_simulator()
        launch = _SIM_SHAPE if simulated else _GPU_SHAPE
        k = model.k if model.neighbours == "topological" else 0
        self._features = features(model)
        self._species = len(model.species_counts)
        self._taus = [x.delay for x in models]
        self._k = kernels = cuda_kernels.build(precision, d, k, launch, self._features, self._species,
                                               max(self._taus) > 0)
        real = kernels.real
        self._real = real
        self._width = kernels.width
        self._rows = max(1, min(1024, 2**22 // max(1, r * d)))
        per_particle = any(s.n and not np.all(s.speeds == s.speeds[0]) for s in states)
        step = states[0].step if states else 0
        self._cells = cells = int(np.prod(cell_grid(model)))
        self._P = cuda.to_device(geometry_record(model, real, replicas=r, rows=self._rows, speeds=per_particle))
        # a constant speed is the state's (a species may set it apart from model.speed)
        self._speed = [real(x.species_values("speed")[0]) for x in models] if kinds else [
            real(s.speeds[0] if s.n else x.speed) for x, s in zip(models, states)]
        rp = np.zeros(r, dtype=cuda_kernels.replica_dtype(real))
        for i, (x, v) in enumerate(zip(models, self._speed)):
            rp[i] = (x.seed, x.delay, x.noise, x.alignment, v)
        self._rp = cuda.to_device(rp)
        self._tables = cuda_kernels.DeviceTables(*(cuda.to_device(a) for a in device_tables(models, real)))
        self._per_particle = per_particle

        self._block, self._qb = launch.block, -(-n // launch.block)
        self._passes = passes(max(1, (r * cells - 1).bit_length()), launch.bits)
        m = r * n
        dev = cuda.device_array
        size = m if per_particle else 1
        self._cur = cuda_kernels.Particles(dev((d, m), real), dev((d, m), real), dev(size, real), dev(m, np.int32))
        self._new = cuda_kernels.Particles(dev((d, m), real), dev((d, m), real), dev(size, real), dev(m, np.int32))
        self._rec, self._rec2 = dev(m, np.uint64), dev(m, np.uint64)
        self._start = cuda_init.zeros(r * cells + 1, np.int32)
        self._start[r * cells:].copy_to_device(np.array([m], dtype=np.int32))
        self._partial = dev((self._width, r * self._qb), np.float64)
        self._phi = cuda.to_device(np.zeros((r, self._rows, self._width)))
        self.moments = np.zeros((r, 0, self._width))
        self._clock = cuda.to_device(np.array([step, 1], dtype=np.int64))
        sort = kernels.sort
        self._hist = cuda.to_device(np.zeros(sort.max_passes * sort.digits_per_pass, dtype=np.int32))
        self._tile_counter = cuda.to_device(np.zeros(sort.max_passes, dtype=np.int32))
        self._status = cuda_init.zeros(-(-m // sort.tile) * sort.digits_per_pass, np.int64)
        # (slot, particle, sums): the cpu backend's layout, a step reads and writes the slab
        # of slot t % tau
        width = ring_width(d, self._features)
        self._ring = cuda_init.zeros((max(self._taus), m, width) if max(self._taus) else (1, 1, width), real)
        self._step_count = step
        self._graphs = graphs and not simulated
        self._graph = None
        if kinds:
            self._draw(kinds)
        else:
            self._load(states, memories or [None] * r)

    # -- device plumbing -------------------------------------------------------------

    def _load(self, states: list[State], memories: Sequence[dict | None]) -> None:
        """Upload the states (id order) into the ``new_*`` buffers, then sort them in."""
        real, n, d = self._real, self.n, self.dim
        box = cuda_init.fold_lengths(self.models[0], real)[:d].astype(real)
        pos, head = np.empty((d, self.replicas * n), real), np.empty((d, self.replicas * n), real)
        for r, s in enumerate(states):
            p = s.positions.astype(real)
            p = np.where(p >= box, p - box, p)  # rounding may reach L (not at a wall)
            pos[:, r * n:(r + 1) * n] = p.T
            head[:, r * n:(r + 1) * n] = s.headings.T
        self._new.pos.copy_to_device(pos)
        self._new.head.copy_to_device(head)
        self._new.ids.copy_to_device(np.tile(np.arange(n, dtype=np.int32), self.replicas))
        if self._per_particle:
            self._new.spd.copy_to_device(np.concatenate([s.speeds for s in states]).astype(real))
        k = self._k
        k.cells[self.replicas * self._qb, self._block](self._new.pos, self._P, self._rec)
        self._sort(tick=False)
        if max(self._taus):
            self._load_ring(memories)

    def _draw(self, kinds: list[str]) -> None:
        """Draw the states of ``kinds`` on the device into the ``new_*`` buffers
        (:mod:`flocking.backends.cuda_init`), then sort them in: no array of N on the host."""

        cuda, m = self._cuda, self.replicas * self.n
        draw, _ = cuda_init.build(self.precision, self.dim)
        seeds = cuda.to_device(np.array([x.seed for x in self.models], dtype=np.uint64))
        box = np.ones(3)
        box[: self.dim] = self.models[0].box
        fold = cuda.to_device(cuda_init.fold_lengths(self.models[0], self._real))
        draw[max(1, -(-m // self._block)), self._block](self._new.pos, self._new.head, self._new.ids, seeds,
                                                         cuda.to_device(box), fold, self.n, kinds[0] == "aligned")
        self._k.cells[self.replicas * self._qb, self._block](self._new.pos, self._P, self._rec)
        self._sort(tick=False)
        if max(self._taus):
            self._load_ring([None] * self.replicas)

    def polar_order_now(self) -> np.ndarray:
        """Each replica's polar order of the state on the device, ``(R,)``, from the moment
        sums the last sort left per block, added in a fixed order on the device."""

        _, reduce = cuda_init.build(self.precision, self.dim)
        out = self._cuda.device_array((self.replicas, self._width), np.float64)
        reduce[self.replicas, max(32, self._width)](self._partial, self._qb, out)
        total = heading_total(out.copy_to_host(), self.dim, self._species)
        return np.sqrt(np.sum(total * total, axis=1)) / max(self.n, 1)

    def _load_ring(self, memories: Sequence[dict | None]) -> None:
        """The delay ring: from each replica's memory, or primed with today's sums."""
        n = self.n
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
            width = self._ring.shape[2]
            if saved.shape != (tau, n, width):
                raise ParameterError(f"resume: the saved delay ring has shape {saved.shape}, "
                                     f"not (delay, n, {width}) = {(tau, n, width)}")
            ring[:tau, r * n:(r + 1) * n] = saved
        self._ring.copy_to_device(ring)

    def launches(self, prime: bool = False, tick: bool = True, stream=0) -> list:
        """The kernel launches of one step, in order, each as ``(name, a function that
        makes it)``: the step kernel, then the sort of its records by cell into the live
        arrays, the cell starts and the moment sums (``gather``), and ``finish``. With
        ``tick`` the step counter moves on and the polar order goes into its row; ``prime``
        (filling the delay ring at the start) is the step kernel alone. :meth:`advance`
        makes them one after another or replays them as a CUDA graph;
        ``benchmarks/cuda_anatomy.py`` times each alone."""
        k, block, grid = self._k, self._block, self.replicas * self._qb
        out = [("step", lambda: k.step[grid, block, stream](self._cur, self._start, self._new, self._rec, self._P,
                                                             self._rp, self._tables, self._clock, self._ring, prime))]
        if prime:
            return out
        return out + self._sort_launches(tick, stream)

    def _sort_launches(self, tick: bool, stream=0) -> list:
        k, block = self._k, self._block
        sorting, src = radix_launches(k.sort, self._rec, self._rec2, self.replicas * self.n, self._passes,
                                      self._hist, self._status, self._tile_counter, self._clock, tick, stream)
        return sorting + [
            ("gather", lambda: k.gather[self.replicas * self._qb, block, stream](
                src, self._new, self._P, self._cur, self._start, self._partial, self._tables.bounds)),
            ("finish", lambda: k.finish[self.replicas, block, stream](
                self._partial, self._P, self._phi, self._clock, self._hist, self._tile_counter, tick))]

    def _launch_step(self, prime: bool = False, stream=0) -> None:
        for _, launch in self.launches(prime=prime, stream=stream):
            launch()

    def _sort(self, tick: bool) -> None:
        """Sort ``rec`` (id order) by cell into the live arrays; cell starts; with
        ``tick``, the step counter moves on and the polar order goes into its row."""
        for _, launch in self._sort_launches(tick):
            launch()

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
    def graphs(self) -> bool:
        """Whether steps are replayed as a captured CUDA graph (else launched from the host)."""
        return self._graphs

    @property
    def rows(self) -> int:
        """Steps whose polar order the device holds before it must be copied back."""
        return self._rows

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; the polar order of every replica after each, ``(R, steps)``.
        With extensions, :attr:`moments` holds every replica's moment sums of these steps
        (:func:`flocking.observables.moment_sums`), ``(R, steps, width)``."""
        steps = int(steps)
        out = np.empty((self.replicas, steps))
        self.moments = np.empty((self.replicas, steps, self._width))
        d = self.dim
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
            self.moments[:, done:done + chunk] = sums
            total = heading_total(sums, d, self._species)
            out[:, done:done + chunk] = np.sqrt(np.sum(total * total, axis=2)) / self.n
            self._step_count += chunk
            done += chunk
        return out

    def fields(self, grid) -> np.ndarray:
        """Every replica's sums ``(R, species, channel, bin)`` of :class:`flocking.fields.Grid`
        ``grid``, binned on the device from the live arrays: only the sums come back."""
        from . import field_kernels

        cuda = self._cuda
        inv, shape = field_kernels.geometry(grid)
        out = cuda.to_device(np.zeros((self.replicas, grid.species, grid.width, grid.bins)))
        kernel = field_kernels.build("cuda", grid.dim, grid.species, grid.nematic)
        m = self.replicas * self.n
        bounds = cuda.to_device(np.asarray(grid.bounds, dtype=np.int64))
        kernel[max(1, -(-m // self._block)), self._block](self._cur.pos, self._cur.head, self._cur.ids, bounds,
                                                          cuda.to_device(inv), cuda.to_device(shape), self.n, out)
        return out.copy_to_host()

    def states(self) -> list[State]:
        """Copies in particle-id order, float64 (float32 headings renormalised), each
        brought over in pieces of :data:`COPY_CHUNK` particles straight into its place:
        the host holds the states and one piece, never a second array of N."""
        n, d = self.n, self.dim
        box = cuda_init.fold_lengths(self.models[0], np.float64)[:d]
        cur = self._cur
        out = []
        for r, model in enumerate(self.models):
            pos, head = np.empty((n, d)), np.empty((n, d))
            spd = np.empty(n) if self._per_particle else np.broadcast_to(np.float64(self._speed[r]), (n,))
            for first in range(r * n, (r + 1) * n, COPY_CHUNK):
                last = min(first + COPY_CHUNK, (r + 1) * n)
                pid = cur.ids[first:last].copy_to_host()
                for a in range(d):
                    pos[pid, a] = cur.pos[a, first:last].copy_to_host()
                    head[pid, a] = cur.head[a, first:last].copy_to_host()
                if self._per_particle:
                    spd[pid] = cur.spd[first:last].copy_to_host()
            if self.precision != "float64":
                head /= np.linalg.norm(head, axis=1, keepdims=True)
                np.subtract(pos, box, out=pos, where=pos >= box)  # float32(L) may exceed L: fold back (not at a wall)
            out.append(State(pos, head, spd, self._step_count))
        return out

    def memory(self) -> list[dict[str, np.ndarray]]:
        """Per replica, the delay ring in the cpu backend's layout ``(delay, N, d + 1)``,
        indexed by id (``{}`` without a delay)."""
        n = self.n
        if not max(self._taus):
            return [{} for _ in self.models]
        ring = self._ring.copy_to_host().astype(np.float64)
        out = []
        for r, tau in enumerate(self._taus):
            if not tau:
                out.append({})
                continue
            out.append({"ring": ring[:tau, r * n:(r + 1) * n].copy()})
        return out


def device_states(models: Sequence[Model], states: Sequence) -> tuple[list[State], list[str]]:
    """``(states, kinds)``: the replicas' states as given, or, where every entry is a kind
    of :data:`flocking.backends.cuda_init.KINDS` that the device can draw
    (:func:`~flocking.backends.cuda_init.drawable`), no states and those kinds; kinds the
    device cannot draw are drawn on the host."""
    from .cuda_init import KINDS, drawable

    states = list(states)
    if len(states) != len(models):
        raise ParameterError(f"states: one per model ({len(models)}; got {len(states)})")
    for s in states:
        if isinstance(s, str) and s not in KINDS:
            raise ParameterError(f"state: must be a State or one of {', '.join(map(repr, KINDS))} (got {s!r})")
    if states and all(isinstance(s, str) for s in states) and all(map(drawable, models)) \
            and len(set(states)) == 1:
        return [], states
    return [getattr(State, s)(m) if isinstance(s, str) else s for m, s in zip(models, states)], []


def radix_sort(records: np.ndarray, key_bits: int = 31, launch: Launch | None = None) -> np.ndarray:
    """``records`` (uint64) sorted stably by their upper 32 bits, which must be below
    ``2**key_bits``, by the device's radix sort (the sort of every step, on its own).

    ``launch`` is the :class:`~flocking.backends.cuda_sort.Launch` shape; by default the
    one the backend uses on this device (or under the simulator).
    """
    cuda = require_cuda()
    from . import cuda_sort

    if _simulated():
        _steady_simulator()
    launch = Launch(*launch) if launch else (_SIM_SHAPE if _simulated() else _GPU_SHAPE)
    k = cuda_sort.build(launch)
    records = np.ascontiguousarray(records, dtype=np.uint64)
    m = len(records)
    if m == 0:
        return records.copy()
    rec, rec2 = cuda.to_device(records), cuda.device_array(m, np.uint64)
    hist = cuda.to_device(np.zeros(k.max_passes * k.digits_per_pass, dtype=np.int32))
    tiles = cuda.to_device(np.zeros(k.max_passes, dtype=np.int32))
    status = cuda.to_device(np.zeros(-(-m // k.tile) * k.digits_per_pass, dtype=np.int64))
    clock = cuda.to_device(np.array([0, 1], dtype=np.int64))
    return cuda_sort.radix(k, rec, rec2, m, cuda_sort.passes(key_bits, launch.bits), hist, status, tiles, clock,
                           False).copy_to_host()


def geometry_record(model: Model, real, replicas: int = 1, rows: int = 1, speeds: bool = False) -> np.ndarray:
    """The kernels' geometry record ``P`` (:func:`flocking.backends.cuda_kernels.geometry_dtype`)
    of ``model``, for ``replicas`` replicas, ``rows`` rows of the moment table and
    per-particle ``speeds`` or one (an array of one record; each value converted to
    ``real`` as the kernels' constants are)."""
    from .cuda_kernels import geometry_dtype

    d = model.dim
    box = np.asarray(model.box, dtype=np.float64)
    nc = cell_grid(model)
    nc3 = [int(x) for x in nc] + [1] * (3 - d)
    box3 = list(box) + [1.0] * (3 - d)
    walls3 = list(model.walls) + [False] * (3 - d)
    values = dict(nc0=nc3[0], nc1=nc3[1], nc2=nc3[2], n=model.n, cells=int(np.prod(nc)), replicas=replicas,
                  vectorial=int(model.noise_type == "vectorial"), backward=int(model.update == "backward"),
                  speeds=int(speeds), rows=rows, obstacles=len(model.obstacles),
                  w0=int(walls3[0]), w1=int(walls3[1]), w2=int(walls3[2]),
                  r2=model.radius**2, width=float(np.min(box / nc)), dt=model.dt)
    half3 = list(Space.of(model).half) + [0.5] * (3 - d)
    for a in range(3):
        values[f"inv{a}"] = nc3[a] / box3[a]
        values[f"l{a}"] = box3[a]
        values[f"h{a}"] = half3[a]
        values[f"s{a}"] = image_shift(box3[a], walls3[a])
    dtype = geometry_dtype(real)
    record = np.zeros(1, dtype=dtype)
    for name in dtype.names:
        record[0][name] = values[name] if dtype[name].kind == "i" else real(values[name])
    return record


def device_tables(models: Sequence[Model], real) -> tuple[np.ndarray, ...]:
    """The fields of :class:`flocking.backends.cuda_kernels.DeviceTables` for replicas
    ``models`` (which share :data:`SHARED`), from :func:`flocking.backends.features.tables`,
    converted to ``real``: the species' values per replica ``(R, S, 5)``, then the first
    model's bounds (int32, as the ids: held in registers for the species look-up of every
    neighbour, 64-bit bounds cost the extended steps up to 12 more registers), coupling,
    field, beta, pair and obstacles (an unused row when there are none). The plain
    model's kernels take them and read none."""
    each = [tables(x) for x in models]
    first = each[0]
    obstacles = first.obstacles if len(first.obstacles) else np.zeros((1, models[0].dim + 1))
    species = np.stack([tb.species for tb in each]).astype(real)
    return (species, first.bounds.astype(np.int32), first.coupling.astype(real), first.field.astype(real),
            first.beta.astype(real), first.pair.astype(real), obstacles.astype(real))


def check_supported(models: Sequence[Model]) -> None:
    """Refuse, in one line, Voronoi neighbours and models whose moment sums (``dim`` per
    species, then the nematic products) do not fit the kernels' shared memory (:data:`MAX_WIDTH`)."""
    for model in models:
        if model.neighbours == "voronoi":
            raise ParameterError("neighbours: the cuda backend has no 'voronoi' neighbours: use 'cpu'")
        width = moment_width(model)
        if width > MAX_WIDTH:
            nematic = " and the nematic order" if model.alignment_rule == "nematic" else ""
            raise ParameterError(
                f"species: the cuda backend records at most {MAX_WIDTH} sums a step ({len(model.species_counts)} "
                f"species in {model.dim}D{nematic} need {width}): use 'cpu'")


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
        if model.extended != first.extended:
            raise ParameterError(f"models: every replica must have extensions or none (model 0 has "
                                 f"{list(first.extensions)}, model {i} {list(model.extensions)})")


class CUDABackend:
    """Cell lists on an NVIDIA GPU, one thread per particle; ``precision`` is
    ``"float64"`` (default) or ``"float32"``; ``graphs=False`` launches every kernel
    from the host (see :class:`Engine`)."""

    name = "cuda"
    #: ``state`` may be ``"random"`` or ``"aligned"``: drawn on the device (:meth:`Engine._draw`)
    draws_states = True

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

    def polar_order_now(self) -> float:
        """The polar order of the state on the device (no copy of it)."""
        return float(self._engine.polar_order_now()[0])

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

    def fields(self, grid) -> np.ndarray:
        """The sums ``(species, channel, bin)`` of ``grid``, binned on the device (:meth:`Engine.fields`)."""
        return self._engine.fields(grid)[0]

    @property
    def moments(self) -> np.ndarray:
        """The moment sums of each step of the last :meth:`advance`, ``(steps, width)``
        (:func:`flocking.observables.moment_sums`: per species ``sum u``, then the nematic
        products)."""
        return self._engine.moments[0]

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (one copy per
        :attr:`Engine.rows` steps)."""
        return self._engine.advance(steps)[0]
