"""What a tab of ``flocking play`` costs, and the budget that all tabs of a server share.

A step is priced before it runs by the backend that runs it
(:meth:`~flocking.backends.cpu.CPUBackend.step_cost`, from where the particles are).

A tab's memory is the backend's (:meth:`~flocking.backends.cpu.CPUBackend.bytes_needed`)
plus the copies a frame makes (:func:`session_bytes`). A :class:`Budget` shares a
server's memory and its cores among its tabs: a tab that does not fit is refused with a
message that says why, and each running tab may step at most its equal share of the cores.
"""

from __future__ import annotations

import math
import threading

import numba

from ..backends.cpu import CPUBackend
from ..model import Model, ParameterError

#: bytes a particle of a frame costs beyond the backend: the state copied in id order and
#: the encoder's temporaries (tests/test_play_server.py checks the sum against tracemalloc)
FRAME_BYTES_PER_DIM = 26
FRAME_BYTES = 24

#: what all tabs of a server may hold together, unless ``flocking play --max-memory`` says
DEFAULT_MEMORY = 1024 * 2**20
MiB = 2**20


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
