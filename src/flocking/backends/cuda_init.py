"""Initial states drawn on the GPU, arrays zeroed there, and the moment sums of the state
the device holds.

:func:`draw` is :meth:`flocking.State.random` (and ``aligned``) as a kernel: a thread per
particle draws its position and heading from the same counter-based numbers
(:func:`flocking.rng.draw`, keyed by the replica's seed, step 0, the particle's id and the
streams ``POSITION + axis``, ``HEADING + j``) with the same arithmetic, and writes them in
the run's precision as :class:`~flocking.backends.cuda.Engine` would have uploaded them
(a float32 coordinate that rounds up to ``L`` along a periodic axis folded back by ``L``).
No array of ``N`` exists on the host. Models with obstacles (their positions are drawn
again until they fall outside) or with speeds that differ between particles are drawn on
the host instead (:func:`drawable`).

:func:`zeros` makes a zeroed device array without a host array behind it (the cell
starts, the sort's status words, the delay ring: each as large as ``N`` or more).

``reduce`` adds the block sums that the gather kernel leaves in ``partial`` per replica,
in a fixed order: the moment sums (and so the polar order) of the state on the device.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .. import rng
from ..rules import compile as compile_rules
from ..rules import rebind
from .sizes import varying_speeds

#: the kinds of state drawn here
KINDS = ("random", "aligned")

R = cuda = None
DIM, REAL = 2, np.float64
POSITION, HEADING = rng.POSITION, rng.HEADING
TWO_PI = 2.0 * np.pi  # as State.random's 2.0 * np.pi * u


def drawable(model) -> bool:
    """Whether the device draws ``model``'s initial state: no obstacles, one speed."""
    return not model.obstacles and not varying_speeds(model)


def draw_state(pos, head, ids, seeds, box, fold, n, aligned):
    """Thread ``i``: particle ``i % n`` of replica ``i // n`` (ids in order)."""
    i = cuda.grid(1)
    if i >= pos.shape[1]:
        return
    r = i // n
    pid = i - r * n
    seed = seeds[r]
    for a in range(DIM):
        x = R.draw(seed, 0, pid, POSITION + a) * box[a]
        if x >= box[a]:  # u * L can round up to L: the half-open interval, as State.random
            x = 0.0
        p = REAL(x)
        if p >= fold[a]:  # the upload's fold of a float32 that rounds up to L (periodic axes)
            p = p - fold[a]
        pos[a, i] = p
    if aligned:
        head[0, i] = REAL(1.0)
        for a in range(1, DIM):
            head[a, i] = REAL(0.0)
    elif DIM == 2:
        angle = TWO_PI * R.draw(seed, 0, pid, HEADING)
        head[0, i] = REAL(math.cos(angle))
        head[1, i] = REAL(math.sin(angle))
    else:
        z = 2.0 * R.draw(seed, 0, pid, HEADING) - 1.0
        rho = math.sqrt(max(0.0, 1.0 - z * z))
        angle = TWO_PI * R.draw(seed, 0, pid, HEADING + 1)
        head[0, i] = REAL(rho * math.cos(angle))
        head[1, i] = REAL(rho * math.sin(angle))
        head[2, i] = REAL(z)
    ids[i] = pid


def reduce(partial, qb, out):
    """Thread ``(r, a)``: the block sums ``partial[a, r qb : (r + 1) qb]`` in order into ``out[r, a]``."""
    r = cuda.blockIdx.x
    a = cuda.threadIdx.x
    if a >= partial.shape[0]:
        return
    acc = 0.0
    for b in range(qb):
        acc += partial[a, r * qb + b]
    out[r, a] = acc


@functools.lru_cache(maxsize=None)
def build(precision: str, dim: int):
    """``(draw, reduce)`` kernels for ``precision`` and ``dim``."""
    from numba import cuda as numba_cuda

    real = np.float64 if precision == "float64" else np.float32
    namespace = {**globals(), "R": compile_rules("cuda", np.float64), "cuda": numba_cuda, "DIM": dim,
                 "REAL": real}
    return numba_cuda.jit(rebind(draw_state, namespace)), numba_cuda.jit(rebind(reduce, namespace))


def fill(flat, value):
    """``flat[i] = value``, a thread per entry."""
    i = cuda.grid(1)
    if i < flat.shape[0]:
        flat[i] = value


@functools.lru_cache(maxsize=None)
def filler():
    from numba import cuda as numba_cuda

    return numba_cuda.jit(rebind(fill, {**globals(), "cuda": numba_cuda}))


def zeros(shape, dtype):
    """A device array of ``shape`` and ``dtype`` set to zero on the device."""
    from numba import cuda as numba_cuda

    out = numba_cuda.device_array(shape, dtype)
    if out.size:
        filler()[-(-out.size // 256), 256](out.reshape(out.size), 0)
    return out


def fold_lengths(model, real) -> np.ndarray:
    """Per axis (3 entries) the length a coordinate at or above which is folded back by
    it (rounding may reach it; a coordinate may be exactly ``L`` at a wall): ``L`` in the
    precision ``real`` along periodic axes, infinity along walls; float64 values.

    >>> from flocking import Model
    >>> fold_lengths(Model(n=10, box=(2.1, 2.0), boundary="periodic,wall"), np.float32).tolist()
    [2.0999999046325684, inf, inf]
    """
    out = np.full(3, np.inf)
    for a, (length, wall) in enumerate(zip(model.box, model.walls)):
        if not wall:
            out[a] = float(real(length))
    return out
