"""Coarse-grained fields, compiled: the particles' sums per bin of a grid, on the CPU (numba)
and on the GPU (numba.cuda), without a copy of the particles.

A bin is found by the engine's own cell rule (:func:`flocking.rules.geometry.cell_index`,
``m`` bins of width ``L / m`` per axis, clamped), so a particle's bin is that of the cell
grid the engine would build with ``m`` cells. Per species ``s`` a particle adds to its bin
``1`` (the count), its heading ``u`` (the polarisation) and, for nematic runs, the nematic
products of :func:`flocking.rules.physics.nematic_2d` / ``nematic_3d`` (those of
:func:`flocking.observables.moment_sums`). The sums are float64 whatever the run's
precision; counts are whole numbers, exact up to ``2**53``.

Layout: ``out[r, s, channel, bin]`` with the bin index ``(iz * m1 + iy) * m0 + ix``
(C order of a ``(z, y, x)`` array). :class:`flocking.fields.Grid` says what each channel is.

The CPU pass visits the slots in order (a serial loop: one pass over ``N`` particles, about
the cost of a tenth of a step). The GPU kernel takes a thread per slot and adds with
atomics: counts are exact, the float sums are those of the particles to rounding, in an
order the device chooses.
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from ..rules import compile as compile_rules
from ..rules import rebind

#: the values a build binds (see :func:`build`)
R = cuda = None
DIM, NSPECIES, NEM = 2, 1, 0


def bin_of(pos, i, inv0, inv1, inv2, m0, m1, m2):
    """The bin of slot ``i`` (``pos`` ``(d, M)``, any float type; binned in float64),
    numbered as the engine numbers its cells (:func:`flocking.rules.geometry.cell_number`)."""
    cz = 0
    if DIM == 3:
        cz = R.cell_index(np.float64(pos[2, i]), inv2, m2)
    return R.cell_number(R.cell_index(np.float64(pos[0, i]), inv0, m0), R.cell_index(np.float64(pos[1, i]), inv1, m1),
                         cz, m0, m1)


def species_row(pid, bounds):
    """The species of particle ``pid`` (0 with one species)."""
    if NSPECIES > 1:
        return R.species_of(pid, bounds, NSPECIES)
    return 0


def deposit_cpu(pos, head, ids, bounds, inv, shape, out):
    """Every slot's sums into ``out[0]`` (``(1, S, W, bins)``, zeroed by the caller)."""
    for i in range(pos.shape[1]):
        b = bin_of(pos, i, inv[0], inv[1], inv[2], shape[0], shape[1], shape[2])
        s = species_row(ids[i], bounds)
        out[0, s, 0, b] += 1.0
        for a in range(DIM):
            out[0, s, 1 + a, b] += np.float64(head[a, i])
        if NEM:
            wx, wy = np.float64(head[0, i]), np.float64(head[1, i])
            if DIM == 2:
                c, t = R.nematic_2d(wx, wy)
                out[0, s, 3, b] += c
                out[0, s, 4, b] += t
            else:
                m = R.nematic_3d(wx, wy, np.float64(head[2, i]))
                for e in range(6):
                    out[0, s, 4 + e, b] += m[e]


def deposit_cuda(pos, head, ids, bounds, inv, shape, n, out):
    """A thread per slot: its sums into ``out[slot // n]`` with atomic adds."""
    i = cuda.grid(1)
    if i >= pos.shape[1]:
        return
    r = i // n
    b = bin_of(pos, i, inv[0], inv[1], inv[2], shape[0], shape[1], shape[2])
    s = species_row(ids[i], bounds)
    cuda.atomic.add(out, (r, s, 0, b), 1.0)
    for a in range(DIM):
        cuda.atomic.add(out, (r, s, 1 + a, b), np.float64(head[a, i]))
    if NEM:
        wx, wy = np.float64(head[0, i]), np.float64(head[1, i])
        if DIM == 2:
            c, t = R.nematic_2d(wx, wy)
            cuda.atomic.add(out, (r, s, 3, b), c)
            cuda.atomic.add(out, (r, s, 4, b), t)
        else:
            m = R.nematic_3d(wx, wy, np.float64(head[2, i]))
            for e in range(6):
                cuda.atomic.add(out, (r, s, 4 + e, b), m[e])


@functools.lru_cache(maxsize=None)
def build(target: str, dim: int, species: int, nematic: bool):
    """The deposit for ``target`` (``"cpu"``: an njit function; ``"cuda"``: a kernel), the
    rules compiled in float64 with the build's values bound as globals."""
    namespace = {**globals(), "R": compile_rules(target, np.float64), "DIM": dim, "NSPECIES": species,
                 "NEM": bool(nematic)}
    if target == "cpu":
        jit = numba.njit(inline="always", error_model="numpy")
        for name in ("bin_of", "species_row"):
            namespace[name] = jit(rebind(globals()[name], namespace))
        return numba.njit(error_model="numpy")(rebind(deposit_cpu, namespace))
    from numba import cuda

    namespace["cuda"] = cuda
    for name in ("bin_of", "species_row"):
        namespace[name] = cuda.jit(device=True)(rebind(globals()[name], namespace))
    return cuda.jit(rebind(deposit_cuda, namespace))


def geometry(grid) -> tuple[np.ndarray, np.ndarray]:
    """``(inv, shape)`` of a :class:`flocking.fields.Grid` as the deposits take them: bins
    per unit length (float64) and bins per axis (int64), three entries each."""
    shape = np.ones(3, dtype=np.int64)
    shape[: grid.dim] = grid.shape
    inv = np.ones(3)
    inv[: grid.dim] = np.asarray(grid.shape, dtype=np.float64) / np.asarray(grid.box)
    return inv, shape


def cpu_fields(grid, pos: np.ndarray, head: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The sums ``(S, W, bins)`` of the particles in ``pos``, ``head`` ``(d, N)`` and ``ids``."""
    inv, shape = geometry(grid)
    out = np.zeros((1, grid.species, grid.width, grid.bins))
    deposit = build("cpu", grid.dim, grid.species, grid.nematic)
    deposit(pos, head, ids, np.asarray(grid.bounds, dtype=ids.dtype), inv, shape, out)
    return out[0]
