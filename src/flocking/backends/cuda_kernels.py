"""CUDA kernels of the GPU backend (numba.cuda), for one system or an ensemble of them.

The physics is :mod:`flocking.rules`, compiled as CUDA device functions for the run's
float type and the build's features (``R = compile_rules("cuda", real, features)``): the
same text as the CPU kernels', so in float64 a GPU step matches a CPU or reference step to
rounding. Every constant is a ``real``, so float32 kernels never silently promote to
float64; only the moment sums are accumulated in float64. The kernels here are thin loops
around those rules.

Layout. ``R`` replicas of ``N`` particles each (``R = 1`` for one system) share every
array: replica ``r`` owns the slots ``[r N, (r + 1) N)``, kept in the order (cell, id),
and the cells ``[r C, (r + 1) C)`` of the cell starts. A particle's *global id* is
``r N + id``. Launches that work per particle use blocks aligned to replicas (block ``b``
is replica ``b // QB``, ``QB = ceil(N / BLOCK)``), so sums per block are the same whether
a system runs alone or in an ensemble.

Arguments travel as named records: :class:`Particles` (positions, headings, speeds, ids),
the geometry record ``P[0]`` (:func:`geometry_dtype`), the replicas' records ``rp[r]``
(:func:`replica_dtype`) and :class:`DeviceTables` (the extensions' values). Kernels, in
the order of a step (every argument is a device array or a flag fixed for the run, so the
same launches repeat every step and can be captured in a CUDA graph; the step number
lives on the device in ``clock[0]``):

``step``
    neighbour sums (row-contiguous cell ranges, or the k nearest by
    :func:`flocking.rules.neighbours.knearest`), delay ring, new heading and position into
    the ``new`` particles (same slot), and the sort record ``rec[global id] = (new cell
    << 32) | slot``: a scatter by id, so that ``rec`` is in id order;
``digits``, ``scatter``
    the radix sort (:mod:`flocking.backends.cuda_sort`);
``gather``
    the particle arrays into the new order (each slot reads the slot it came from), the
    cell starts (a binary search per cell in the sorted cells), and each block's moment
    sums (float64: per species ``sum u``, then the nematic products);
``finish``
    per replica, the block sums in a fixed order into one row of the moment table;
    readies the sort's counters for the next step.

What :class:`~flocking.backends.features.Features` leaves off is not compiled in; walls,
obstacles, species values, chirality and the field are data. Safety: cells are clamped
(:func:`flocking.rules.geometry.cell_index`), ranges come from the cell starts, the sort
never trusts its input beyond the number of particles: no kernel reads or writes out of
bounds, whatever the coordinates (NaN, infinite, 1e300).
"""

from __future__ import annotations

import functools
import types
import typing

import numpy as np
from numba import cuda

from ..observables import sums_width
from ..rules import compile as compile_rules
from ..rules import rebind
from . import cuda_sort
from .cuda_sort import KEY, LOW, Launch
from .features import Features


class Particles(typing.NamedTuple):
    """The particle arrays of one buffer: ``pos`` and ``head`` ``(d, M)``, ``spd`` (``M``,
    or one entry for constant speeds) and ``ids`` (``M``, int32)."""

    pos: typing.Any
    head: typing.Any
    spd: typing.Any
    ids: typing.Any


class DeviceTables(typing.NamedTuple):
    """:class:`flocking.backends.features.Tables` on the device, in the run's float type,
    for every replica: ``species`` ``(R, S, 5)``; ``bounds`` (int32, as the ids),
    ``coupling``, ``field``, ``beta``, ``pair`` as there; ``obstacles``
    ``(max(M, 1), d + 1)`` (an unused row when there are none)."""

    species: typing.Any
    bounds: typing.Any
    coupling: typing.Any
    field: typing.Any
    beta: typing.Any
    pair: typing.Any
    obstacles: typing.Any


def geometry_dtype(real) -> np.dtype:
    """The geometry record ``P``: cells per axis ``nc*``, particles per replica ``n``, cells
    per replica, replicas, flags (vectorial noise, backward update, per-particle speeds),
    rows of the moment table, obstacles, walls per axis ``w*``; then, in ``real``, ``inv*`` (cells per unit
    length), box sides ``l*``, the minimum image's half-lengths ``h*`` (infinite across
    walls), the shifts of wrapped cells ``s*`` (``L``, or ``2L`` across walls: out of
    reach), ``r2``, the narrowest cell ``width`` and ``dt``."""
    ints = ["nc0", "nc1", "nc2", "n", "cells", "replicas", "vectorial", "backward", "speeds", "rows", "obstacles",
            "w0", "w1", "w2"]
    reals = ["inv0", "inv1", "inv2", "l0", "l1", "l2", "h0", "h1", "h2", "s0", "s1", "s2", "r2", "width", "dt"]
    return np.dtype([(name, np.int64) for name in ints] + [(name, real) for name in reals], align=True)


def replica_dtype(real) -> np.dtype:
    """A replica's record: its ``seed`` (uint64), delay ``tau``, noise ``eta``, alignment
    ``epsilon`` and constant speed ``v0``."""
    return np.dtype([("seed", np.uint64), ("tau", np.int64), ("eta", real), ("epsilon", real), ("v0", real)],
                    align=True)


# The values of a build: the functions below read them as globals, and build() compiles
# each with its own values in place of these (the float type's constants, the flags of
# Features, each field in capitals, and the delay's, the dimension, k, the moment width,
# the launch shape; the rules with the build's switches, R).
R = None
EXTENDED = COUPLING = NEMATIC = CONE = COHESION = DELAY = False
DIM, K, KA, NSPECIES, WIDTH, BLOCK, HSIZE, PMAX = 2, 0, 1, 1, 2, 256, 1, 1
REAL, ZERO, ONE = np.float64, 0.0, 1.0


# -- neighbours --------------------------------------------------------------------

def x_ranges(cx, nc0, length):
    """The x-cells of a row around ``cx`` as at most two contiguous runs of cells,
    each with the shift that brings its particles to the nearest image (cells at
    least R wide); fewer than 3 cells: one run of all, minimum image per pair."""
    if nc0 < 3:
        return 0, nc0, ZERO, 0, 0, ZERO
    if cx == 0:
        return 0, 2, ZERO, nc0 - 1, nc0, length
    if cx == nc0 - 1:
        return nc0 - 2, nc0, ZERO, 0, 1, -length
    return cx - 1, cx + 2, ZERO, 0, 0, ZERO

def row_of(c, oc, nc, length):
    """Neighbour row ``oc`` (0..2, or 0..nc-1 when nc < 3) of cell ``c``: index and shift."""
    if nc < 3:
        return oc, ZERO
    g = c - 1 + oc
    if g < 0:
        return g + nc, length
    if g >= nc:
        return g - nc, -length
    return g, ZERO

def terms(i, j, dx, dy, dz, d2, inside, cur, tb, si):
    """Neighbour candidate ``j`` of slot ``i`` by :func:`flocking.rules.physics.neighbour`.
    Compiled twice per build: with the build's rules (``R``), and as ``ranked_terms`` with
    the cone left out (``RANKED``) for the k nearest, which are ranked among those in the
    cone."""
    head = cur.head
    coupling = tb.coupling[si, R.species_of(cur.ids[j], tb.bounds, NSPECIES)] if COUPLING else ONE
    uz = head[2, i] if DIM == 3 else ZERO
    vz = head[2, j] if DIM == 3 else ZERO
    return R.neighbour(DIM, dx, dy, dz, d2, inside, head[0, i], head[1, i], uz, head[0, j], head[1, j], vz,
                       coupling, R.pair_values(tb.pair))


#: :func:`terms` with the cone left out, for the k nearest: compiled per build without it
ranked_terms = terms

def metric(i, cb, cur, start, p, tb, si):
    """The others within R of slot ``i`` (``cb``: the replica's first cell): weighed
    heading sum (3), count, pull (3), push (3), core count. Wrapped cells are shifted
    by ``s*`` (``2L`` across a wall: out of reach); an axis of fewer than three cells
    takes the minimum image per pair."""
    pos = cur.pos
    # read once: a record field read in the candidate loop is a load from memory there
    nc0, nc1, nc2, r2 = p.nc0, p.nc1, p.nc2, p.r2
    xi, yi = pos[0, i], pos[1, i]
    zi = pos[2, i] if DIM == 3 else ZERO
    cx, cy = R.cell_index(xi, p.inv0, nc0), R.cell_index(yi, p.inv1, nc1)
    cz = R.cell_index(zi, p.inv2, nc2) if DIM == 3 else 0
    a0, a1, sha, b0, b1, shb = x_ranges(cx, nc0, p.s0)
    s = R.SUM0
    nz = R.lesser(nc2, 3) if DIM == 3 else 1
    for oz in range(nz):
        gz, shz = row_of(cz, oz, nc2, p.s2) if DIM == 3 else (0, ZERO)
        for oy in range(R.lesser(nc1, 3)):
            gy, shy = row_of(cy, oy, nc1, p.s1)
            row = cb + R.cell_number(0, gy, gz, nc0, nc1)
            for run in range(2):
                if run == 0:
                    lo, hi, shx = start[row + a0], start[row + a1], sha
                else:
                    lo, hi, shx = start[row + b0], start[row + b1], shb
                for j in range(lo, hi):
                    if j == i:
                        continue
                    if nc0 >= 3:
                        dx = (pos[0, j] - xi) - shx
                    else:
                        dx = R.minimum_image(pos[0, j] - xi, p.l0, p.h0)
                    if nc1 >= 3:
                        dy = (pos[1, j] - yi) - shy
                    else:
                        dy = R.minimum_image(pos[1, j] - yi, p.l1, p.h1)
                    d2 = dx * dx + dy * dy
                    dz = ZERO
                    if DIM == 3:
                        if nc2 >= 3:
                            dz = (pos[2, j] - zi) - shz
                        else:
                            dz = R.minimum_image(pos[2, j] - zi, p.l2, p.h2)
                        d2 += dz * dz
                    t = terms(i, j, dx, dy, dz, d2, d2 < r2, cur, tb, si)
                    if t[3] != ZERO:
                        s = R.plus(s, t)
    return s

def nearest(i, cb, cur, start, p, tb, si, bd, bi, bs):
    """The K nearest others of slot ``i``, as :func:`metric`."""
    pos = cur.pos
    xi, yi = pos[0, i], pos[1, i]
    zi = pos[2, i] if DIM == 3 else ZERO
    c0, c1 = R.cell_index(xi, p.inv0, p.nc0), R.cell_index(yi, p.inv1, p.nc1)
    c2 = R.cell_index(zi, p.inv2, p.nc2) if DIM == 3 else 0
    found = R.knearest(i, c0, c1, c2, cb, pos, cur.head, cur.ids, start, p.nc0, p.nc1, p.nc2, p.l0, p.l1, p.l2,
                       p.h0, p.h1, p.h2, DIM, K, CONE, R.cone_of(R.pair_values(tb.pair)), bd, bi, bs)
    s = R.SUM0
    for q in range(K):
        if q < found:
            j = bs[q]
            dx = R.minimum_image(pos[0, j] - xi, p.l0, p.h0)
            dy = R.minimum_image(pos[1, j] - yi, p.l1, p.h1)
            dz = R.minimum_image(pos[2, j] - zi, p.l2, p.h2) if DIM == 3 else ZERO
            s = R.plus(s, ranked_terms(i, j, dx, dy, dz, bd[q], True, cur, tb, si))
    return s

# -- one step --------------------------------------------------------------------

def cell_of(x, y, z, p):
    """The cell of a point in its replica (:func:`flocking.rules.geometry.cell_number`;
    ``z`` unused in 2D)."""
    cz = R.cell_index(z, p.inv2, p.nc2) if DIM == 3 else 0
    return R.cell_number(R.cell_index(x, p.inv0, p.nc0), R.cell_index(y, p.inv1, p.nc1), cz, p.nc0, p.nc1)


def slot_of(n):
    """This thread's replica ``r``, its slot in the replica (``>= n``, replicas of ``n``
    particles, where it has none) and its slot in the arrays: a replica takes
    ``ceil(n / BLOCK)`` blocks."""
    qb = (n + BLOCK - 1) // BLOCK
    r = cuda.blockIdx.x // qb
    local = (cuda.blockIdx.x % qb) * BLOCK + cuda.threadIdx.x
    return r, local, r * n + local

def step(cur, start, new, rec, P, rp, tb, clock, ring, prime):
    """One step of a slot into ``new[:, slot]`` and its sort record into
    ``rec[global id]``. ``ring[t % tau, global id]`` (tau > 0) holds the sums of tau
    steps ago (the others' heading sum, ``1 +`` their count, with cohesion the pull,
    the push and the core count: the cpu backend's layout, ``features.ring_width``
    values) and receives today's; a build without ``DELAY`` has no ring code. With
    ``prime``, only fill every ring slot with today's sums (the initial state stands in
    for the past)."""
    p = P[0]
    n = p.n
    r, local, i = slot_of(n)
    if local >= n:
        return
    cb = r * p.cells
    pid = cur.ids[i]
    if DELAY:
        gid = r * n + pid
        t = clock[0]
        tau = rp[r].tau
        slot = t % tau if tau > 0 else 0
        past = R.SUM0
        if tau > 0 and not prime:
            # read before the neighbour search, whose work hides the latency of these
            # reads (scattered by id over the ring's slab): read after it, they made a
            # delayed step 2.8 times slower (docs/gpu.md)
            past = R.recall(ring, slot, gid, DIM, COHESION)
    si = R.species_of(pid, tb.bounds, NSPECIES) if EXTENDED else 0
    if K == 0:
        s = metric(i, cb, cur, start, p, tb, si)
    else:
        # ids and slots fit int32 (``start`` is int32): 64-bit entries took 7 more
        # registers for each, and a third fewer blocks per SM (topological 2D float32)
        bd = cuda.local.array(KA, REAL)
        bi = cuda.local.array(KA, np.int32)
        bs = cuda.local.array(KA, np.int32)
        s = nearest(i, cb, cur, start, p, tb, si, bd, bi, bs)
    s = R.counted(s)
    if not DELAY:
        # here, not before the search: held across it, they took 3 more registers
        gid = r * n + pid
        t = clock[0]
    else:
        if prime:
            for q in range(tau):
                R.keep(ring, q, gid, s, DIM, COHESION)
            return
        if tau > 0:
            R.keep(ring, slot, gid, s, DIM, COHESION)
            s = past  # without cohesion its last seven are zeros that move() never reads
    move(i, pid, gid, r, cb, s, cur, new, rec, p, rp, tb, si, t)

def move(i, pid, gid, r, cb, s, cur, new, rec, p, rp, tb, si, t):
    """From the others' sums ``s`` to slot ``i``'s new heading, position and sort
    record: the step's end as both backends take it (:func:`flocking.rules.step.finish`)."""
    pos, head = cur.pos, cur.head
    ux, uy = head[0, i], head[1, i]
    uz = head[2, i] if DIM == 3 else ZERO
    s = R.with_own(s, ONE, ux, uy, uz)
    if EXTENDED:
        eta, epsilon = tb.species[r, si, 0], tb.species[r, si, 1]
        cturn, sturn, h = tb.species[r, si, 2], tb.species[r, si, 3], tb.species[r, si, 4]
    else:
        eta, epsilon, h, cturn, sturn = rp[r].eta, rp[r].epsilon, ZERO, ONE, ZERO
    if p.speeds != 0:
        ds = cur.spd[i] * p.dt
        new.spd[i] = cur.spd[i]
    else:
        ds = rp[r].v0 * p.dt
    z = pos[2, i] if DIM == 3 else ZERO
    x, y, z, wx, wy, wz = R.finish(DIM, EXTENDED, COHESION, ux, uy, uz, s, tb.beta[0], (eta, epsilon, h, cturn, sturn),
                                   p.vectorial != 0, p.backward != 0, rp[r].seed, np.uint64(t), np.uint64(pid),
                                   (tb.field[0], tb.field[1], tb.field[2]), ds, pos[0, i], pos[1, i], z,
                                   (p.l0, p.l1, p.l2), (p.h0, p.h1, p.h2), (p.w0 != 0, p.w1 != 0, p.w2 != 0),
                                   tb.obstacles, p.obstacles)
    new.head[0, i], new.head[1, i] = wx, wy
    new.pos[0, i], new.pos[1, i] = x, y
    if DIM == 3:
        new.head[2, i], new.pos[2, i] = wz, z
    c = cell_of(x, y, z, p)
    new.ids[i] = pid
    rec[gid] = (np.uint64(cb + c) << KEY) | np.uint64(i)

def cells(pos, P, rec):
    """Sort records of positions in global-id order (a state being loaded)."""
    p = P[0]
    n = p.n
    r, local, i = slot_of(n)
    if local >= n:
        return
    c = cell_of(pos[0, i], pos[1, i], pos[2, i] if DIM == 3 else ZERO, p)
    rec[i] = (np.uint64(r * p.cells + c) << KEY) | np.uint64(i)

# -- back into slots, cell starts, moments ------------------------------------------

def block_sum(buf, tid):
    """Tree sum of the shared ``buf[:, :BLOCK]`` into ``buf[:, 0]``, in a fixed order;
    every thread of the block calls it."""
    cuda.syncthreads()
    stride = BLOCK // 2
    while stride > 0:
        if tid < stride:
            for a in range(WIDTH):
                buf[a, tid] += buf[a, tid + stride]
        cuda.syncthreads()
        stride //= 2

def gather(srt, new, P, cur, start, partial, bounds):
    """Slot ``s`` takes the particle the sort put there (``srt[s]`` holds the slot it
    came from); each cell's start is found by a binary search in the replica's sorted
    records; each block's moment sums (float64, :func:`flocking.rules.step.add_moments`)
    go to ``partial``."""
    buf = cuda.shared.array((WIDTH, BLOCK), np.float64)
    p = P[0]
    n, ncells = p.n, p.cells
    tid = cuda.threadIdx.x
    r, local, _ = slot_of(n)
    for a in range(WIDTH):
        buf[a, tid] = 0.0
    if local < n:
        s = r * n + local  # here, not from slot_of: held over the loop above, 38-40 registers, not 32
        o = np.int64(srt[s] & LOW)
        for a in range(DIM):
            cur.pos[a, s] = new.pos[a, o]
            cur.head[a, s] = new.head[a, o]
        wz = np.float64(new.head[2, o]) if DIM == 3 else 0.0
        R.add_moments(buf, tid, new.ids[o], bounds, NSPECIES, DIM, NEMATIC, np.float64(new.head[0, o]),
                      np.float64(new.head[1, o]), wz)
        cur.ids[s] = new.ids[o]
        if p.speeds != 0:
            cur.spd[s] = new.spd[o]
    if local < ncells:  # cells never outnumber particles
        key = np.uint64(r * ncells + local)
        lo, hi = r * n, r * n + n
        while lo < hi:
            mid = (lo + hi) // 2
            if (srt[mid] >> KEY) < key:
                lo = mid + 1
            else:
                hi = mid
        start[r * ncells + local] = lo
    block_sum(buf, tid)
    if tid == 0:
        for a in range(WIDTH):
            partial[a, cuda.blockIdx.x] = buf[a, 0]

def finish(partial, P, phi, clock, hist, tiles, tick):
    """Block ``r``: replica ``r``'s block sums, in a fixed order, into row
    ``clock[0] % rows`` of ``phi`` (with ``tick``). Block 0 also readies the sort's
    counters for the next sort."""
    buf = cuda.shared.array((WIDTH, BLOCK), np.float64)
    p = P[0]
    qb = (p.n + BLOCK - 1) // BLOCK
    r = cuda.blockIdx.x
    tid = cuda.threadIdx.x
    if r == 0:
        for e in range(tid, HSIZE, BLOCK):
            hist[e] = 0
        if tid < PMAX:
            tiles[tid] = 0
        if tid == 0:
            clock[1] += 1
    if tick:
        for a in range(WIDTH):
            acc = 0.0
            for b in range(tid, qb, BLOCK):
                acc += partial[a, r * qb + b]
            buf[a, tid] = acc
        block_sum(buf, tid)
        if tid == 0:
            row = clock[0] % p.rows
            for a in range(WIDTH):
                phi[r, row, a] = buf[a, 0]


#: the device functions of a build, callees first
DEVICE = ('cell_of', 'slot_of', 'x_ranges', 'row_of', 'terms', 'metric', 'nearest', 'move', 'block_sum')
#: the kernels of a build
KERNELS = ('step', 'cells', 'gather', 'finish')


@functools.lru_cache(maxsize=None)
def build(precision: str, dim: int, k: int, launch: Launch, features: Features = Features(),
          species: int = 1, delay: bool = False) -> types.SimpleNamespace:
    """The kernels for one precision (``"float64"``/``"float32"``), dimension, ``k`` (0:
    metric), launch shape (:class:`~flocking.backends.cuda_sort.Launch`), ``features``
    (what is compiled in), number of ``species`` (the width of the moment sums) and
    ``delay`` (whether any replica has one: the delay ring's reads and writes).

    The functions of :data:`DEVICE` and :data:`KERNELS` are compiled from their text with
    these values as their globals (as :func:`flocking.rules.compile` binds the rules'
    constants), so what ``features`` leaves off is not compiled."""
    real = np.float64 if precision == "float64" else np.float32
    R = compile_rules("cuda", real, features)
    DIM, K, KA, NSPECIES, DELAY = dim, k, max(k, 1), species, delay
    WIDTH = sums_width(dim, species, features.nematic)
    BLOCK = launch.block
    sort = cuda_sort.build(launch)
    HSIZE, PMAX = sort.hist_size, sort.max_passes
    ZERO, ONE = real(0.0), real(1.0)
    namespace = {**globals(), **features.flags(), "R": R, "DIM": DIM,
                 "K": K, "KA": KA, "NSPECIES": NSPECIES, "DELAY": DELAY, "WIDTH": WIDTH, "BLOCK": BLOCK,
                 "HSIZE": HSIZE, "PMAX": PMAX, "REAL": real, "ZERO": ZERO, "ONE": ONE}
    ranked = {**namespace, "R": compile_rules("cuda", real, features._replace(cone=False))}
    namespace["ranked_terms"] = cuda.jit(device=True)(rebind(terms, ranked, "ranked_terms"))
    for name in DEVICE:
        namespace[name] = cuda.jit(device=True)(rebind(globals()[name], namespace))
    for name in KERNELS:
        namespace[name] = cuda.jit(rebind(globals()[name], namespace))
    step, cells, gather, finish = (namespace[name] for name in KERNELS)

    return types.SimpleNamespace(real=real, step=step, cells=cells, gather=gather, finish=finish, sort=sort,
                                 width=WIDTH, block=BLOCK)


def signatures(precision: str, dim: int, species: int = 1) -> dict[str, tuple]:
    """Each kernel's argument types for :func:`build` at ``precision``: what numba's
    ``cuda.compile_ptx`` needs to compile a kernel without a GPU (the tests and
    ``benchmarks/bench_cuda.py --ptx`` do)."""
    from numba import types as nt
    from numba.np import numpy_support

    real = nt.float64 if precision == "float64" else nt.float32
    dtype = np.float64 if precision == "float64" else np.float32
    i64, i32, u64, f64, b = nt.int64, nt.int32, nt.uint64, nt.float64, nt.boolean

    def a(dt, nd):
        return nt.Array(dt, nd, "C")

    particles = nt.NamedTuple([a(real, 2), a(real, 2), a(real, 1), a(i32, 1)], Particles)
    tb = nt.NamedTuple([a(real, 3), a(i32, 1), a(real, 2), a(real, 1), a(real, 1), a(real, 1), a(real, 2)],
                       DeviceTables)
    P = nt.Array(numpy_support.from_dtype(geometry_dtype(dtype)), 1, "C")
    rp = nt.Array(numpy_support.from_dtype(replica_dtype(dtype)), 1, "C")
    return {
        "step": (particles, a(i32, 1), particles, a(u64, 1), P, rp, tb, a(i64, 1), a(real, 3), b),
        "cells": (a(real, 2), P, a(u64, 1)),
        "gather": (a(u64, 1), particles, P, particles, a(i32, 1), a(f64, 2), a(i32, 1)),
        "finish": (a(f64, 2), P, a(f64, 3), a(i64, 1), a(i32, 1), a(i32, 1), b),
        "digits": (a(u64, 1), a(i32, 1), i64, i64, a(i64, 1), b),
        "scatter": (a(u64, 1), a(u64, 1), i64, i64, a(i32, 1), a(i64, 1), a(i32, 1), a(i64, 1)),
    }
