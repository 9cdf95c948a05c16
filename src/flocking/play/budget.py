"""What a tab of ``flocking play`` costs, and the budget that all tabs of a server share.

A step is priced before it runs, from where the particles are: the cpu backend visits,
for every particle, the particles of the ``3^d`` cells around its own, so a step costs
about ``n * particle + candidates * candidate`` nanoseconds, where ``candidates`` is the
sum over cells of ``n_c`` times the particles in the block of cells around ``c``
(:func:`step_cost`). A flock spread evenly over the box at density 2 has about 19
candidates a particle; all of it packed into one cell has ``n``. :data:`COSTS` holds the
nanoseconds per particle and per candidate of each kernel. A model with extensions
(:attr:`flocking.Model.extended`: walls, obstacles, species, a vision cone, chirality)
runs a step of :mod:`flocking.backends.cpu_kernels` compiled for them (dearer where each pair
is weighted), and each obstacle adds :data:`OBSTACLE_COST` per particle.

A tab's memory is the backend's (:meth:`~flocking.backends.cpu.CPUBackend.bytes_needed`)
plus the copies a frame makes (:func:`session_bytes`). A :class:`Budget` shares a
server's memory and its cores among its tabs: a tab that does not fit is refused with a
message that says why, and each running tab may step at most its equal share of the cores.

>>> from flocking import Model, State
>>> model = Model(n=4000, density=2.0)
>>> seconds, candidates = step_cost(model, State.random(model).positions)
>>> round(candidates)  # 9 cells of about 2.2 particles around each particle
20
>>> packed = np.full((4000, 2), 0.5)  # every particle in one cell
>>> step_cost(model, packed)[1]
4000.0
"""

from __future__ import annotations

import math
import threading

import numba
import numpy as np

from ..backends.cells import cell_grid
from ..backends.cpu import CPUBackend, kernel_name
from ..backends.features import features
from ..model import Model, ParameterError

#: nanoseconds of one core per particle and per neighbour candidate in a step, by kernel
#: (``topological``: per particle and neighbour sought, ``k + 1``); measured on the
#: project's 2-core machine while other programs kept it busy, so rather high. In 3D a
#: particle costs twice as much. The extended steps (any extension on) were measured
#: against the plain one on one thread, N = 10^4 at density 2, spread out and crowded into
#: 2 % of the box (docs/play.md): on a metric grid of at least three cells a side, without
#: pair weights as the plain step (walls and chirality: 200 ns and 1.8 ns measured), with
#: them (a coupling matrix, nematic alignment, a vision cone) about 1.2 times per particle
#: and 2 to 3 times per candidate (220 to 310 ns and 3.4 to 5 ns);
#: elsewhere (a box under ``3R``) 7 times the plain cost per particle, 20 times per candidate.
COSTS = {"lines": (300.0, 2.0), "generic": (300.0, 25.0), "topological": (250.0, 2.5),
         "extended lines": (300.0, 2.5), "extended weighted": (350.0, 6.0),
         "extended": (2500.0, 50.0), "extended topological": (450.0, 15.0),
         "voronoi": (22000.0, 0.0)}  # Qhull's triangulation, serial: 2.2 s a step at N = 1e5 (docs/voronoi.md)
#: nanoseconds per particle and obstacle: each particle is tested against every obstacle
OBSTACLE_COST = 25.0

#: bytes a particle of a frame costs beyond the backend: the state copied in id order and
#: the encoder's temporaries (tests/test_play_server.py checks the sum against tracemalloc)
FRAME_BYTES_PER_DIM = 26
FRAME_BYTES = 24

#: what all tabs of a server may hold together, unless ``flocking play --max-memory`` says
DEFAULT_MEMORY = 1024 * 2**20
MiB = 2**20


def kernel(model: Model) -> str:
    """Which of :data:`COSTS` prices ``model``'s step: the cpu backend's kernel
    (:func:`flocking.backends.cpu.kernel_name`) and what it compiles in
    (:func:`flocking.backends.features.features`): ``lines`` (metric, at least three
    cells a side), ``generic`` (metric, a box under ``3R`` along some axis),
    ``topological``, or with any extension ``extended lines`` (no pair weights),
    ``extended weighted`` (a coupling matrix, nematic alignment, a vision cone or
    cohesion), ``extended`` (a box under ``3R``) and ``extended topological``.

    >>> kernel(Model(n=100, box=10.0)), kernel(Model(n=100, box=10.0, boundary="wall"))
    ('lines', 'extended lines')
    >>> kernel(Model(n=100, box=10.0, vision=2.0)), kernel(Model(n=100, box=2.5, vision=2.0))
    ('extended weighted', 'extended')
    """
    on = features(model)
    if kernel_name(model) == "lines":
        if not on.extended:
            return "lines"
        return "extended weighted" if on.weighted else "extended lines"
    if model.neighbours == "voronoi":
        return "voronoi"
    if model.neighbours == "topological":
        return "extended topological" if on.extended else "topological"
    return "extended" if on.extended else "generic"


def step_cost(model: Model, positions: np.ndarray) -> tuple[float, float]:
    """Estimated seconds of one core for one step from ``positions``, and the neighbour
    candidates per particle that the estimate counted."""
    n, d = positions.shape
    nc = cell_grid(model)
    candidates = _candidates(positions, nc, nc / np.asarray(model.box, dtype=np.float64))
    name = kernel(model)
    particle, candidate = COSTS[name]
    if name.endswith("topological"):
        particle *= model.k + 1
    particle *= 1 if d == 2 else (5.5 if name == "voronoi" else 2)  # 3D Voronoi: 1.2 s at N = 1e4
    particle += OBSTACLE_COST * len(model.obstacles)
    return (n * particle + candidates * candidate) * 1e-9, candidates / max(n, 1)


@numba.njit(cache=True)
def _candidates(positions, nc, inv):
    """Sum over cells of ``n_c`` times the particles in the cells around ``c``, each
    neighbouring cell counted once (a grid of one or two cells a side has fewer)."""
    n, d = positions.shape
    counts = np.zeros(np.prod(nc))
    for i in range(n):
        c = 0
        for a in range(d - 1, -1, -1):  # row-major with x fastest, as the backend numbers cells
            x = positions[i, a] * inv[a]
            ca = 0 if not x >= 0.0 else min(int(x), nc[a] - 1)  # a non-finite flock is stopped, not priced
            c = c * nc[a] + ca
        counts[c] += 1.0
    span = np.minimum(nc, 3)  # distinct neighbouring cells per axis
    ny = nc[1]
    nz = nc[2] if d == 3 else 1
    total = 0.0
    for c in range(counts.shape[0]):
        if counts[c] == 0.0:
            continue
        cx = c % nc[0]
        cy = (c // nc[0]) % ny
        cz = c // (nc[0] * ny)
        around = 0.0
        for kz in range(span[2] if d == 3 else 1):
            z = (cz + kz - 1 + nz) % nz if d == 3 else 0
            for ky in range(span[1]):
                y = (cy + ky - 1 + ny) % ny
                for kx in range(span[0]):
                    x = (cx + kx - 1 + nc[0]) % nc[0]
                    around += counts[(z * ny + y) * nc[0] + x]
        total += counts[c] * around
    return total


def session_bytes(model: Model) -> int:
    """Memory of one tab running ``model``: the backend's and a frame's.

    >>> model = Model(n=200_000, density=2.0)
    >>> session_bytes(model) - CPUBackend.bytes_needed(model) == 76 * model.n  # a frame, in 2D
    True
    """
    per_particle = FRAME_BYTES_PER_DIM * model.dim + FRAME_BYTES
    return CPUBackend.bytes_needed(model) + model.n * per_particle


class Budget:
    """The memory, the cores and the number of tabs that the tabs of one server share.

    Tabs are any objects; :meth:`join` admits one with the memory it needs, :meth:`reserve`
    changes what it holds, :meth:`leave` frees it. Each running tab (one whose
    ``running`` attribute is true) may step :meth:`share` cores. Thread-safe.

    >>> budget = Budget(memory=100 * MiB, cores=2.0, tabs=2)
    >>> a, b = object(), object()
    >>> budget.join(a, 60 * MiB); budget.join(b, 30 * MiB); budget.share()  # cores for each
    1.0
    >>> budget.reserve(b, 50 * MiB, "n")
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: n: this needs 50 MiB, but only 40 MiB of the 100 MiB that all tabs share are free; lower n or close another tab
    >>> budget.join(object(), 1)
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: too many open tabs (at most 2); close one
    >>> budget.leave(a); budget.reserve(b, 50 * MiB, "n"); budget.share()
    2.0
    """

    def __init__(self, memory: int = DEFAULT_MEMORY, cores: float | None = None, tabs: int = 16):
        self.memory = int(memory)
        self.cores = float(numba.config.NUMBA_NUM_THREADS if cores is None else cores)
        self.tabs = int(tabs)
        self._held: dict[object, int] = {}
        self._lock = threading.Lock()

    def join(self, tab: object, nbytes: int) -> None:
        """Admit a new tab that needs ``nbytes``, or say why not."""
        with self._lock:
            if len(self._held) >= self.tabs:
                raise ParameterError(f"too many open tabs (at most {self.tabs}); close one")
            free = self.memory - sum(self._held.values())
            if nbytes > free:
                raise ParameterError(f"no memory left for another tab: it needs {_mib(nbytes)}, and "
                                     f"{_mib(free)} of the {_mib(self.memory)} that all tabs share are free; "
                                     f"close a tab")
            self._held[tab] = int(nbytes)

    def reserve(self, tab: object, nbytes: int, name: str = "n") -> None:
        """Let ``tab`` hold ``nbytes`` instead of what it held, or raise a
        :class:`ParameterError` about parameter ``name``."""
        with self._lock:
            free = self.memory - sum(v for t, v in self._held.items() if t is not tab)
            if nbytes > free:
                raise ParameterError(f"{name}: this needs {_mib(nbytes)}, but only {_mib(free)} of the "
                                     f"{_mib(self.memory)} that all tabs share are free; lower {name} or close "
                                     f"another tab")
            self._held[tab] = int(nbytes)

    def leave(self, tab: object) -> None:
        with self._lock:
            self._held.pop(tab, None)

    @property
    def held(self) -> int:
        """Bytes held by all tabs."""
        with self._lock:
            return sum(self._held.values())

    def share(self) -> float:
        """Cores that each running tab may use: all of them shared equally."""
        with self._lock:
            running = sum(1 for tab in self._held if getattr(tab, "running", True))
        return self.cores / max(1, running)


def _mib(nbytes: float) -> str:
    """``12 MiB``, or one decimal below 10 MiB."""
    value = nbytes / MiB
    return f"{value:.1f} MiB" if value < 10 else f"{math.floor(value + 0.5):d} MiB"
