"""What a system needs in memory, and the one-line refusal of one that does not fit.

:func:`device_bytes` adds up what :class:`flocking.backends.cuda.Engine` allocates on the
card for ``R`` replicas of a model: per particle the two buffers of positions and headings
(``2 x 2d`` floats of the precision), ids (``2 x 4`` bytes), the sort's two record arrays
(16 bytes) and its tile status (about 1 byte), per-particle speeds where they differ
(``2 x`` a float), the delay ring (``delay x (d + 1)`` floats, more with cohesion); per
cell 4 bytes of cell starts; small tables besides. :func:`check_device` compares that with
the card's free memory and refuses, in one line, a system that does not fit, naming the
largest ``N`` that would (and what float32 would fit). docs/fields.md tabulates the bytes
per particle.

>>> from flocking import Model
>>> per_particle(Model(n=10**6, box=1000.0), "float64"), per_particle(Model(n=10**6, box=1000.0), "float32")
(89.0, 57.0)
>>> per_particle(Model(dim=3, n=10**6, box=100.0), "float64")
121.0
>>> check_device([Model(n=10**8, box=10**4)], "float64", free=4 * 2**30)
Traceback (most recent call last):
...
flocking.checks.ParameterError: n: 100000000 particles (2D, float64) need 8.66 GiB on the GPU, more than the 4 GiB \
free: at most 41330000 fit (float32: at most 64540000)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..checks import ParameterError
from .cells import cell_grid
from .cuda_sort import Launch
from .features import features, ring_width

#: the launch shape whose sort sizes the tile status (the GPU's: 256 threads, 8 bits, 8 items)
GPU_SHAPE = Launch(256, 8, 8)
#: share of the free memory a system may take (the rest: the CUDA context, the kernels' code)
USABLE = 0.95


def varying_speeds(model) -> bool:
    """Whether the particles' speeds differ (then an array on the device, else one number)."""
    return len(set(model.species_values("speed"))) > 1 or "uniform" in model.species_values("speeds")


def per_particle(model, precision: str, launch: Launch = GPU_SHAPE) -> float:
    """Device bytes per particle of ``model`` at ``precision`` (``"float64"`` or ``"float32"``)."""
    real = 8 if precision == "float64" else 4
    d = model.dim
    out = 2 * (2 * d * real + 4) + 16 + 8 * 2**launch.bits / (launch.block * launch.items)
    if varying_speeds(model):
        out += 2 * real
    if model.delay:
        out += model.delay * ring_width(d, features(model)) * real
    return float(out)


def fixed_bytes(model, replicas: int = 1) -> int:
    """Device bytes that do not grow with ``N`` at fixed cells: cell starts, moment rows,
    tables, counters (an upper bound)."""
    cells = int(np.prod(cell_grid(model)))
    return 4 * (replicas * cells + 1) + 8 * 1024 * 20 * replicas + 2**20


def device_bytes(models: Sequence, precision: str = "float64", launch: Launch = GPU_SHAPE) -> int:
    """Device bytes of an engine of ``models`` (replicas of one size): the per-particle
    arrays (the largest delay of them sets the ring) and :func:`fixed_bytes`."""
    models = list(models)
    widest = max(models, key=lambda m: per_particle(m, precision, launch))
    return int(math.ceil(per_particle(widest, precision, launch) * len(models) * widest.n)
               + fixed_bytes(widest, len(models)))


def device_free() -> int | None:
    """Free bytes on the current CUDA device, or ``None`` where that is unknown (no device,
    the simulator)."""
    try:
        from numba import cuda
        from numba.core import config

        if config.ENABLE_CUDASIM or not cuda.is_available():
            return None
        return int(cuda.current_context().get_memory_info()[0])
    except Exception:  # noqa: BLE001 - no answer is no check; the engine reports a missing device
        return None


def largest_n(models: Sequence, precision: str, budget: float) -> int:
    """The largest particle count per replica whose :func:`device_bytes` fits ``budget``,
    rounded down to four significant digits."""
    models = list(models)
    widest = max(models, key=lambda m: per_particle(m, precision))
    n = (budget - fixed_bytes(widest, len(models))) / (per_particle(widest, precision) * len(models))
    return round_down(max(0, int(n)))


def round_down(n: int) -> int:
    """``n`` to four significant digits, downward.

    >>> round_down(123456789), round_down(42)
    (123400000, 42)
    """
    if n < 10**4:
        return n
    scale = 10 ** (len(str(n)) - 4)
    return n // scale * scale


def check_device(models: Sequence, precision: str = "float64", free: int | None = None) -> None:
    """Refuse, in one line, replicas that do not fit in ``free`` bytes of device memory (by
    default the card's, :func:`device_free`; unknown: no check)."""
    free = device_free() if free is None else free
    if not free:
        return
    models = list(models)
    need = device_bytes(models, precision)
    budget = USABLE * free
    if need <= budget:
        return
    model, r = models[0], len(models)
    what = f"{model.n} particles" if r == 1 else f"{r} replicas of {model.n} particles"
    fit = largest_n(models, precision, budget)
    hint = f"at most {fit} fit" if r == 1 else f"at most {fit} particles a replica fit"
    if precision == "float64":
        hint += f" (float32: at most {largest_n(models, 'float32', budget)})"
    raise ParameterError(f"n: {what} ({model.dim}D, {precision}) need {gib(need)} on the GPU, more than the "
                         f"{gib(free)} free: {hint}")


def check_host(model, need: int, available: int, backend: str) -> None:
    """Refuse, in one line, a run whose ``need`` bytes exceed 90% of the ``available``
    host memory, naming the largest ``N`` that would fit (bytes grow as ``N``)."""
    if not available or need <= 0.9 * available:
        return
    fit = round_down(int(model.n * 0.9 * available / need))
    raise ParameterError(f"n: {model.n} particles need about {gib(need)} with backend {backend!r}, more than "
                         f"the {gib(available)} available: at most about {fit} fit")


def gib(x: float) -> str:
    """Bytes in GiB, three significant digits."""
    return f"{x / 2**30:.3g} GiB"
