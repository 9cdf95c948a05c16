"""CUDA kernels of the GPU backend (numba.cuda), for one system or an ensemble of them.

The per-particle arithmetic is :mod:`flocking.backends.kernels` (``update_2d``,
``update_3d``, ``wrap``, ``minimum_image``) transcribed line by line, in the same order of
floating-point operations, and the random numbers are :func:`flocking.rng._uniform` with
the same uint64 arithmetic: in float64 a GPU step matches a CPU or reference step to
rounding. The arithmetic is written once over a scalar type ``real`` (``np.float64`` or
``np.float32``): every constant is a ``real``, so float32 kernels never silently promote
to float64. Only the polar-order sums are always accumulated in float64.

Layout. ``R`` replicas of ``N`` particles each (``R = 1`` for one system) share every
array: replica ``r`` owns the slots ``[r N, (r + 1) N)``, kept in the order (cell, id),
and the cells ``[r C, (r + 1) C)`` of the cell starts. A particle's *global id* is
``r N + id``. Launches that work per particle use blocks aligned to replicas (block ``b``
is replica ``b // QB``, ``QB = ceil(N / BLOCK)``), so sums per block are the same whether
a system runs alone or in an ensemble.

Kernels, in the order of a step (every argument is a device array or a flag fixed for
the run, so the same launches repeat every step and can be captured in a CUDA graph;
the step number lives on the device in ``clock[0]``):

``step``
    neighbour sums (row-contiguous cell ranges, or a ring search for the k nearest),
    delay ring, new heading and position into ``new_*`` (same slot), and the sort record
    ``rec[global id] = (new cell << 32) | slot``: a scatter by id, so that ``rec`` is in
    id order;
``digits``
    histograms of every radix digit of the cells in ``rec`` (all passes at once);
``scatter``
    one pass of a stable least-significant-digit radix sort: each block ranks one tile
    stably in shared memory, finds where its digits go from the tiles before it
    (decoupled look-back, no extra launch), and writes out. Input in id order, stable
    passes: the result is sorted by (cell, id), a pure function of the state, in
    ``O(N)`` work whatever the number of particles in a cell;
``gather``
    the particle arrays into the new order (each slot reads the slot it came from), the
    cell starts (a binary search per cell in the sorted cells), and each block's heading
    sum (float64);
``finish``
    per replica, the block sums in a fixed order into one row of the polar-order table;
    resets the sort's counters.

Extensions (:class:`Extensions`, fixed at compile time; the plain model's kernels have
none of their code): the step weighs each neighbour by the coupling of the two species and
the nematic sign and keeps only those in the vision cone, takes the species' noise,
alignment, chirality and field strength, and after the move folds positions back across
walls and out of obstacles (:mod:`flocking.backends.cpu_extensions`, transcribed); along
an axis with walls there is no minimum image and wrapped cells are shifted out of reach.
``gather`` and ``finish`` then sum, per block and per replica, each species' headings and
the nematic products (``width`` sums a step instead of ``dim``).

Safety: cells are clamped (:func:`cell_of`), ranges come from the cell starts, the sort
never trusts its input beyond the number of particles: no kernel reads or writes out of
bounds, whatever the coordinates (NaN, infinite, 1e300).
"""

from __future__ import annotations

import functools
import math
import types
import typing

import numpy as np
from numba import cuda

from .. import rng

_GOLDEN, _M1, _M2 = rng._GOLDEN, rng._M1, rng._M2
_S30, _S27, _S31, _S11 = rng._S30, rng._S27, rng._S31, rng._S11
_INV53 = rng._INV53
_NOISE0 = np.uint64(rng.NOISE)
_NOISE1 = np.uint64(rng.NOISE + 1)

#: ``geom``, the real parameters shared by every replica, in this order
GEOM = ("inv0", "inv1", "inv2", "l0", "l1", "l2", "r2", "width", "dt")
#: ``ints``, the integer parameters (flags as 0/1)
INTS = ("nc0", "nc1", "nc2", "n", "cells", "replicas", "vectorial", "backward", "speeds", "rows", "obstacles")
#: ``rp[r]``, the real parameters of one replica
REPLICA = ("eta", "epsilon", "v0")
#: ``xr``, the real parameters of the extensions, in this order
EXT_REAL = ("g0", "g1", "g2", "cos_vision")
#: ``sp[r, s]``, the values of species ``s`` in replica ``r``, in this order
SPECIES = ("noise", "alignment", "turn", "field_strength")


class Extensions(typing.NamedTuple):
    """What :func:`build` fixes at compile time for a model with extensions: walls per
    axis, a vision cone, nematic alignment, a coupling matrix, the number of species.
    Obstacles, the field and chirality are data."""

    walls: tuple[bool, bool, bool] = (False, False, False)
    cone: bool = False
    nematic: bool = False
    coupling: bool = False
    species: int = 1


#: the sort record of a slot no particle fills: sorts after every real one
SENTINEL = np.uint64(0xFFFFFFFFFFFFFFFF)
_LOW = np.uint64(0xFFFFFFFF)
_KEY = np.uint64(32)


@cuda.jit(device=True)
def _absorb(h, x):
    z = h + x
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@cuda.jit(device=True)
def uniform(seed, step, particle, counter):
    """:func:`flocking.rng._uniform` on the device; all four keys are uint64."""
    h = _absorb(_GOLDEN, seed)
    h = _absorb(h, step)
    h = _absorb(h, particle)
    h = _absorb(h, counter)
    return (h >> _S11) * _INV53


def passes(key_bits: int, bits: int) -> int:
    """Radix passes over keys of ``key_bits`` bits, ``bits`` a pass (at least one).

    >>> passes(19, 8), passes(1, 8), passes(24, 4)
    (3, 1, 6)
    """
    return max(1, -(-key_bits // bits))


@functools.lru_cache(maxsize=None)
def build(precision: str, dim: int, k: int, block: int, bits: int, items: int,
          ext: Extensions | None = None) -> types.SimpleNamespace:
    """The kernels for one precision (``"float64"``/``"float32"``), dimension, ``k``
    (0: metric), threads per block (a power of two), radix ``bits`` a pass (at most
    ``log2(block)``, so that each digit has a thread) and sort items a thread; with
    ``ext``, those of a model with extensions (:class:`Extensions`: what is fixed at
    compile time), else the plain model's, where no extension code is compiled in."""
    real = np.float64 if precision == "float64" else np.float32
    EXT = ext is not None
    ext = ext or Extensions()
    WALL0, WALL1, WALL2 = ext.walls
    CONE, NEM, CPL, NSPECIES = ext.cone, ext.nematic, ext.coupling, ext.species
    # rows of the per-step sums: dim per species, then the nematic products (2D: 2, 3D: 6)
    WIDTH = dim * NSPECIES + ((2 if dim == 2 else 6) if NEM else 0)
    ZERO, ONE, HALF, TWO, FOUR = real(0.0), real(1.0), real(0.5), real(2.0), real(4.0)
    TWO_PI, TINY, NEAR_X = real(2.0 * math.pi), real(1e-12), real(0.9)
    INF = real(np.inf)
    DIM, K, KA = dim, k, max(k, 1)
    BLOCK = block
    BITS, DIGITS = bits, 1 << bits
    if DIGITS > BLOCK:
        raise ValueError("build: 2**bits must not exceed block")
    if bits % 2:
        raise ValueError("build: bits must be even")
    # a tile is ranked in two halves of the digit (keys -> other -> keys), with a counter
    # per (half-digit, thread): 16 x BLOCK for 8-bit digits
    SUB = bits // 2
    SUBD = 1 << SUB
    ITEMS, TILE = items, block * items
    PMAX = passes(31, bits)
    HSIZE, CSIZE = PMAX * DIGITS, SUBD * BLOCK  # shared array sizes must be constants
    MASK = np.uint64(DIGITS - 1)
    SUBMASK = np.uint64(SUBD - 1)
    # sub-digit counters: a tile holds at most 32767 items, so int16 counts suffice
    CTYPE = np.int16 if TILE < 2**15 else np.int32

    # -- per-particle arithmetic (kernels.py, transcribed) ---------------------------

    @cuda.jit(device=True)
    def lesser(a, b):
        """``min(a, b)``, as Python's; numba.cuda's builtin ``min`` and ``max`` do not
        compile everywhere (numba 0.68's own numba.cuda fails on them)."""
        return b if b < a else a

    @cuda.jit(device=True)
    def greater(a, b):
        """``max(a, b)``, as Python's: ``a`` unless ``b`` is larger."""
        return b if b > a else a

    @cuda.jit(device=True)
    def minimum_image(dx, length, half):
        if dx > half:
            return dx - length
        if dx < -half:
            return dx + length
        return dx

    @cuda.jit(device=True)
    def halves(l0, l1, l2):
        """Half the box along each axis, the reach of :func:`minimum_image`: infinite along
        an axis with walls, where there is no minimum image."""
        return INF if WALL0 else l0 / TWO, INF if WALL1 else l1 / TWO, INF if WALL2 else l2 / TWO

    @cuda.jit(device=True)
    def wrap(x, length):
        if not abs(x) < INF:  # NaN or infinite (a broken state): left as it is
            return x
        x = x - length * real(math.floor(x / length))
        if x >= length:
            x -= length
        return x

    @cuda.jit(device=True)
    def cell_of(x, inv, nc):
        """The cell of coordinate ``x``, always in ``[0, nc)``: NaN, negative or infinite
        coordinates (a broken state) land in a border cell instead of out of bounds."""
        f = x * inv
        if f >= ZERO:  # false for NaN
            if f < real(nc):
                return int(f)
            return nc - 1
        return 0

    @cuda.jit(device=True)
    def update_2d(ux, uy, sx, sy, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, turn):
        z0 = real(uniform(seed, step, pid, _NOISE0))
        if EXT and h != ZERO:
            sx = sx + h * count * gx
            sy = sy + h * count * gy
        if vectorial:
            angle = TWO_PI * z0
            sx = sx + eta * count * math.cos(angle)
            sy = sy + eta * count * math.sin(angle)
        norm = math.sqrt(sx * sx + sy * sy)
        if norm > ZERO:
            mx, my = sx / norm, sy / norm
        else:
            mx, my = ux, uy
        if epsilon == ONE:
            wx, wy = mx, my
        else:
            a = epsilon * math.atan2(ux * my - uy * mx, ux * mx + uy * my)
            c, s = math.cos(a), math.sin(a)
            wx, wy = ux * c - uy * s, ux * s + uy * c
        if EXT and turn != ZERO:
            c, s = math.cos(turn), math.sin(turn)
            wx, wy = wx * c - wy * s, wx * s + wy * c
        if not vectorial:
            a = eta * (z0 - HALF)
            c, s = math.cos(a), math.sin(a)
            wx, wy = wx * c - wy * s, wx * s + wy * c
        norm = math.sqrt(wx * wx + wy * wy)
        return wx / norm, wy / norm

    @cuda.jit(device=True)
    def update_3d(ux, uy, uz, sx, sy, sz, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, gz):
        z0 = real(uniform(seed, step, pid, _NOISE0))
        z1 = real(uniform(seed, step, pid, _NOISE1))
        if EXT and h != ZERO:
            sx = sx + h * count * gx
            sy = sy + h * count * gy
            sz = sz + h * count * gz
        if vectorial:
            z = TWO * z0 - ONE
            rho = math.sqrt(greater(ZERO, ONE - z * z))
            angle = TWO_PI * z1
            sx = sx + eta * count * (rho * math.cos(angle))
            sy = sy + eta * count * (rho * math.sin(angle))
            sz = sz + eta * count * z
        norm = math.sqrt(sx * sx + sy * sy + sz * sz)
        if norm > ZERO:
            mx, my, mz = sx / norm, sy / norm, sz / norm
        else:
            mx, my, mz = ux, uy, uz
        if epsilon == ONE:
            wx, wy, wz = mx, my, mz
        else:
            c = ux * mx + uy * my + uz * mz
            cx, cy, cz = uy * mz - uz * my, uz * mx - ux * mz, ux * my - uy * mx
            s = math.sqrt(cx * cx + cy * cy + cz * cz)
            if s < TINY:
                if c > ZERO:
                    wx, wy, wz = mx, my, mz
                else:
                    wx, wy, wz = ux, uy, uz
            else:
                alpha = math.atan2(s, c)
                f, g = math.sin((ONE - epsilon) * alpha), math.sin(epsilon * alpha)
                wx, wy, wz = (f * ux + g * mx) / s, (f * uy + g * my) / s, (f * uz + g * mz) / s
        if not vectorial:
            sin_q = math.sin(eta / FOUR)
            cos_b = ONE - z0 * (TWO * (sin_q * sin_q))
            sin_b = math.sqrt(greater(ZERO, ONE - cos_b * cos_b))
            phi = TWO_PI * z1
            if abs(wx) < NEAR_X:
                ax, ay = ONE, ZERO
            else:
                ax, ay = ZERO, ONE
            dot = ax * wx + ay * wy
            e1x, e1y, e1z = ax - dot * wx, ay - dot * wy, ZERO - dot * wz
            n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
            e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
            e2x, e2y, e2z = wy * e1z - wz * e1y, wz * e1x - wx * e1z, wx * e1y - wy * e1x
            cp, sp = math.cos(phi), math.sin(phi)
            wx = cos_b * wx + sin_b * (cp * e1x + sp * e2x)
            wy = cos_b * wy + sin_b * (cp * e1y + sp * e2y)
            wz = cos_b * wz + sin_b * (cp * e1z + sp * e2z)
        norm = math.sqrt(wx * wx + wy * wy + wz * wz)
        return wx / norm, wy / norm, wz / norm

    # -- neighbours ------------------------------------------------------------------

    @cuda.jit(device=True)
    def x_ranges(cx, nc0, length):
        """The x-cells of a row around ``cx`` as at most two contiguous runs of cells,
        each with the shift that brings its particles to the minimum image (cells at
        least R wide); fewer than 3 cells: one run of all, minimum image per pair."""
        if nc0 < 3:
            return 0, nc0, ZERO, 0, 0, ZERO
        if cx == 0:
            return 0, 2, ZERO, nc0 - 1, nc0, length
        if cx == nc0 - 1:
            return nc0 - 2, nc0, ZERO, 0, 1, -length
        return cx - 1, cx + 2, ZERO, 0, 0, ZERO

    @cuda.jit(device=True)
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

    @cuda.jit(device=True)
    def species_of(pid, bounds):
        """The species of particle ``pid``: species are contiguous id ranges, species
        ``s`` from ``bounds[s]`` to ``bounds[s + 1]``."""
        s = 0
        while s + 1 < NSPECIES and pid >= bounds[s + 1]:
            s += 1
        return s

    @cuda.jit(device=True)
    def weight(i, j, head, ids, bounds, cpl, si):
        """``J[s_i][s_j] c_ij``: the weight of neighbour ``j`` in the sum of ``i`` (the
        coupling of their species, times -1 for nematic alignment if their headings point
        apart); 1 in the plain model."""
        w = ONE
        if CPL:
            w = cpl[si, species_of(ids[j], bounds)]
        if NEM:
            dot = head[0, i] * head[0, j] + head[1, i] * head[1, j]
            if DIM == 3:
                dot += head[2, i] * head[2, j]
            if dot < ZERO:
                w = -w
        return w

    @cuda.jit(device=True)
    def seen(i, dx, dy, dz, d2, head, cosv):
        """Whether the other at ``(dx, dy, dz)`` from slot ``i`` is inside its vision
        cone, ``u_i . r >= |r| cos``; always without a cone."""
        if not CONE:
            return True
        dot = head[0, i] * dx + head[1, i] * dy
        if DIM == 3:
            dot += head[2, i] * dz
        return dot >= math.sqrt(d2) * cosv

    @cuda.jit(device=True)
    def metric_sums(i, cb, pos, head, ids, start, nc0, nc1, nc2, inv0, inv1, inv2, l0, l1, l2, r2,
                    bounds, cpl, cosv, si):
        """Weighted heading sum and number of the others within R of slot ``i`` (``cb``:
        the replica's first cell). Along an axis with walls there is no minimum image and
        wrapped cells are shifted by ``2L``, out of reach."""
        h0, h1, h2 = halves(l0, l1, l2)
        s0 = TWO * l0 if WALL0 else l0
        s1 = TWO * l1 if WALL1 else l1
        s2 = TWO * l2 if WALL2 else l2
        xi, yi = pos[0, i], pos[1, i]
        zi = pos[2, i] if DIM == 3 else ZERO
        cx, cy = cell_of(xi, inv0, nc0), cell_of(yi, inv1, nc1)
        cz = cell_of(zi, inv2, nc2) if DIM == 3 else 0
        a0, a1, sha, b0, b1, shb = x_ranges(cx, nc0, s0)
        sx, sy, sz = ZERO, ZERO, ZERO
        count = 0
        nz = lesser(nc2, 3) if DIM == 3 else 1
        for oz in range(nz):
            gz, shz = row_of(cz, oz, nc2, s2) if DIM == 3 else (0, ZERO)
            for oy in range(lesser(nc1, 3)):
                gy, shy = row_of(cy, oy, nc1, s1)
                row = cb + (gz * nc1 + gy) * nc0
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
                            dx = minimum_image(pos[0, j] - xi, l0, h0)
                        if nc1 >= 3:
                            dy = (pos[1, j] - yi) - shy
                        else:
                            dy = minimum_image(pos[1, j] - yi, l1, h1)
                        d2 = dx * dx + dy * dy
                        dz = ZERO
                        if DIM == 3:
                            if nc2 >= 3:
                                dz = (pos[2, j] - zi) - shz
                            else:
                                dz = minimum_image(pos[2, j] - zi, l2, h2)
                            d2 += dz * dz
                        if d2 < r2 and seen(i, dx, dy, dz, d2, head, cosv):
                            w = weight(i, j, head, ids, bounds, cpl, si)
                            sx += w * head[0, j]
                            sy += w * head[1, j]
                            if DIM == 3:
                                sz += w * head[2, j]
                            count += 1
        return sx, sy, sz, count

    @cuda.jit(device=True)
    def better(d2, j, bd, bs, q, ids):
        """Whether candidate (``d2``, slot ``j``) ranks before entry ``q`` of the k best:
        nearer, or as near with the lower id (an empty entry has ``bs[q] < 0``)."""
        if d2 < bd[q]:
            return True
        if d2 == bd[q] and j >= 0:
            return bs[q] < 0 or ids[j] < ids[bs[q]]
        return False

    @cuda.jit(device=True)
    def topological(i, cb, pos, head, ids, start, nc0, nc1, nc2, inv0, inv1, inv2, l0, l1, l2, width, bd, bs,
                    cosv):
        """The K nearest others of slot ``i`` into ``bd``/``bs`` (distance^2, slot),
        nearest first, ties to the lower id; rings of cells outward until the K-th
        distance is inside the searched region (as the CPU backend). Every index into
        ``bd``/``bs`` is a loop counter over ``range(K)``, which the compiler unrolls, so
        the K best live in registers. A NaN distance is never a candidate. Along an axis
        with walls there is no minimum image (the cells across it are far away); with a
        vision cone, only the others inside it are candidates."""
        h0, h1, h2 = halves(l0, l1, l2)
        xi, yi = pos[0, i], pos[1, i]
        zi = pos[2, i] if DIM == 3 else ZERO
        c0, c1 = cell_of(xi, inv0, nc0), cell_of(yi, inv1, nc1)
        c2 = cell_of(zi, inv2, nc2) if DIM == 3 else 0
        lo0, lo1 = (nc0 - 1) // 2, (nc1 - 1) // 2
        hi0, hi1 = nc0 - 1 - lo0, nc1 - 1 - lo1
        lo2 = (nc2 - 1) // 2 if DIM == 3 else 0
        hi2 = nc2 - 1 - lo2 if DIM == 3 else 0
        rmax = greater(greater(lo0, hi0), greater(greater(lo1, hi1), greater(lo2, hi2)))
        for q in range(K):
            bd[q] = INF
            bs[q] = -1
        found = 0
        r = 0
        while True:
            for o0 in range(-lesser(r, lo0), lesser(r, hi0) + 1):
                for o1 in range(-lesser(r, lo1), lesser(r, hi1) + 1):
                    for o2 in range(-lesser(r, lo2), lesser(r, hi2) + 1):
                        if greater(abs(o0), greater(abs(o1), abs(o2))) != r:
                            continue
                        g0 = (c0 + o0) % nc0
                        g1 = (c1 + o1) % nc1
                        if DIM == 2:
                            c = cb + g1 * nc0 + g0
                        else:
                            c = cb + (((c2 + o2) % nc2) * nc1 + g1) * nc0 + g0
                        for j in range(start[c], start[c + 1]):
                            if j == i:
                                continue
                            dx = minimum_image(pos[0, j] - xi, l0, h0)
                            dy = minimum_image(pos[1, j] - yi, l1, h1)
                            d2 = dx * dx + dy * dy
                            dz = ZERO
                            if DIM == 3:
                                dz = minimum_image(pos[2, j] - zi, l2, h2)
                                d2 += dz * dz
                            if not seen(i, dx, dy, dz, d2, head, cosv):
                                continue
                            if not better(d2, j, bd, bs, K - 1, ids):
                                continue
                            cd, cs = d2, j
                            for q in range(K):  # one bubble pass: static indices only
                                if better(cd, cs, bd, bs, q, ids):
                                    bd[q], cd = cd, bd[q]
                                    bs[q], cs = cs, bs[q]
                            if found < K:
                                found += 1
            if r >= rmax:
                break
            reach = real(r) * width
            if found == K and bd[K - 1] < reach * reach:
                break
            r += 1
        return found

    # -- walls and obstacles -----------------------------------------------------------

    @cuda.jit(device=True)
    def fold(x, u, length, wall):
        """After a move, one coordinate and the heading's component along its axis:
        folded back across a wall (the component turned into the box), or wrapped."""
        if wall:
            if x < ZERO:
                return -x, abs(u)
            if x > length:
                return TWO * length - x, -abs(u)
            return x, u
        return wrap(x, length), u

    @cuda.jit(device=True)
    def bounce(x, y, z, wx, wy, wz, l0, l1, l2, obs, nobs):
        """Walls, then each obstacle in order: a particle inside one is moved to its
        mirror point ``c + (2a - d) n`` and its heading reflected if it points inward
        (as :func:`flocking.backends.cpu_extensions._bounce`)."""
        h0, h1, h2 = halves(l0, l1, l2)
        x, wx = fold(x, wx, l0, WALL0)
        y, wy = fold(y, wy, l1, WALL1)
        if DIM == 3:
            z, wz = fold(z, wz, l2, WALL2)
        for o in range(nobs):
            r0 = minimum_image(x - obs[o, 0], l0, h0)
            r1 = minimum_image(y - obs[o, 1], l1, h1)
            r2 = minimum_image(z - obs[o, 2], l2, h2) if DIM == 3 else ZERO
            d2 = r0 * r0 + r1 * r1
            if DIM == 3:
                d2 += r2 * r2
            dist = math.sqrt(d2)
            radius = obs[o, DIM]
            if dist < radius:
                if dist > ZERO:
                    n0, n1, n2 = r0 / dist, r1 / dist, r2 / dist
                else:
                    n0, n1, n2 = -wx, -wy, (-wz if DIM == 3 else ZERO)
                push = TWO * radius - dist
                x = obs[o, 0] + push * n0
                y = obs[o, 1] + push * n1
                if DIM == 3:
                    z = obs[o, 2] + push * n2
                if not WALL0:
                    x = wrap(x, l0)
                if not WALL1:
                    y = wrap(y, l1)
                if DIM == 3 and not WALL2:
                    z = wrap(z, l2)
                dot = wx * n0 + wy * n1
                if DIM == 3:
                    dot += wz * n2
                if dot < ZERO:
                    wx = wx - TWO * dot * n0
                    wy = wy - TWO * dot * n1
                    if DIM == 3:
                        wz = wz - TWO * dot * n2
        return x, y, z, wx, wy, wz

    # -- one step --------------------------------------------------------------------

    @cuda.jit
    def step(pos, head, spd, ids, start, geom, ints, rp, rtau, rseed, clock, ring, prime,
             new_pos, new_head, new_ids, new_spd, rec, sp, bounds, cpl, xr, obs):
        """One step of a slot into ``new_*[:, slot]`` and its sort record into
        ``rec[global id]``. ``ring[t % tau, global id]`` (tau > 0) holds the neighbour
        sums and count (``d + 1`` values, the cpu backend's layout) of tau steps ago and
        receives today's. With ``prime``, only fill every ring slot with today's sums (the
        initial state stands in for the past). With
        extensions: ``sp[r, species]`` (:data:`SPECIES`), the species' first ids
        ``bounds``, the coupling ``cpl``, ``xr`` (:data:`EXT_REAL`) and the obstacles
        ``obs`` (centre, radius; ``ints[10]`` of them); unused otherwise."""
        n = ints[3]
        qb = (n + BLOCK - 1) // BLOCK
        r = cuda.blockIdx.x // qb
        local = (cuda.blockIdx.x % qb) * BLOCK + cuda.threadIdx.x
        if local >= n:
            return
        i = r * n + local
        nc0, nc1, nc2, ncells = ints[0], ints[1], ints[2], ints[4]
        inv0, inv1, inv2, l0, l1, l2 = geom[0], geom[1], geom[2], geom[3], geom[4], geom[5]
        cb = r * ncells
        pid = ids[i]
        si = species_of(pid, bounds)
        if K == 0:
            sx, sy, sz, count = metric_sums(i, cb, pos, head, ids, start, nc0, nc1, nc2,
                                            inv0, inv1, inv2, l0, l1, l2, geom[6], bounds, cpl, xr[3], si)
        else:
            bd = cuda.local.array(KA, real)
            bs = cuda.local.array(KA, np.int64)
            count = topological(i, cb, pos, head, ids, start, nc0, nc1, nc2, inv0, inv1, inv2,
                                l0, l1, l2, geom[7], bd, bs, xr[3])
            sx, sy, sz = ZERO, ZERO, ZERO
            for q in range(K):
                if q < count:
                    j = bs[q]
                    w = weight(i, j, head, ids, bounds, cpl, si)
                    sx += w * head[0, j]
                    sy += w * head[1, j]
                    if DIM == 3:
                        sz += w * head[2, j]
        gid = r * n + pid
        total = ONE + real(count)
        t = clock[0]
        tau = rtau[r]
        if prime:
            for s in range(tau):
                ring[s, gid, 0], ring[s, gid, 1], ring[s, gid, DIM] = sx, sy, total
                if DIM == 3:
                    ring[s, gid, 2] = sz
            return
        if tau > 0:
            s = t % tau
            osx, osy, ototal = ring[s, gid, 0], ring[s, gid, 1], ring[s, gid, DIM]
            ring[s, gid, 0], ring[s, gid, 1], ring[s, gid, DIM] = sx, sy, total
            if DIM == 3:
                osz = ring[s, gid, 2]
                ring[s, gid, 2] = sz
                sz = osz
            sx, sy, total = osx, osy, ototal
        if EXT:
            eta, epsilon, turn, h = sp[r, si, 0], sp[r, si, 1], sp[r, si, 2], sp[r, si, 3]
        else:
            eta, epsilon, turn, h = rp[r, 0], rp[r, 1], ZERO, ZERO
        vectorial = ints[6] != 0
        useed, ustep, upid = rseed[r], np.uint64(t), np.uint64(pid)
        if ints[8] != 0:
            ds = spd[i] * geom[8]
            new_spd[i] = spd[i]
        else:
            ds = rp[r, 2] * geom[8]
        if DIM == 2:
            ux, uy = head[0, i], head[1, i]
            wx, wy = update_2d(ux, uy, ux + sx, uy + sy, total, epsilon, eta, vectorial,
                               useed, ustep, upid, h, xr[0], xr[1], turn)
            mx, my = (wx, wy) if ints[7] != 0 else (ux, uy)
            if EXT:
                x, y, z, wx, wy, wz = bounce(pos[0, i] + ds * mx, pos[1, i] + ds * my, ZERO,
                                             wx, wy, ZERO, l0, l1, l2, obs, ints[10])
            else:
                x = wrap(pos[0, i] + ds * mx, l0)
                y = wrap(pos[1, i] + ds * my, l1)
            new_head[0, i], new_head[1, i] = wx, wy
            new_pos[0, i], new_pos[1, i] = x, y
            c = cell_of(y, inv1, nc1) * nc0 + cell_of(x, inv0, nc0)
        else:
            ux, uy, uz = head[0, i], head[1, i], head[2, i]
            wx, wy, wz = update_3d(ux, uy, uz, ux + sx, uy + sy, uz + sz, total, epsilon, eta,
                                   vectorial, useed, ustep, upid, h, xr[0], xr[1], xr[2])
            mx, my, mz = (wx, wy, wz) if ints[7] != 0 else (ux, uy, uz)
            if EXT:
                x, y, z, wx, wy, wz = bounce(pos[0, i] + ds * mx, pos[1, i] + ds * my, pos[2, i] + ds * mz,
                                             wx, wy, wz, l0, l1, l2, obs, ints[10])
            else:
                x = wrap(pos[0, i] + ds * mx, l0)
                y = wrap(pos[1, i] + ds * my, l1)
                z = wrap(pos[2, i] + ds * mz, l2)
            new_head[0, i], new_head[1, i], new_head[2, i] = wx, wy, wz
            new_pos[0, i], new_pos[1, i], new_pos[2, i] = x, y, z
            c = (cell_of(z, inv2, nc2) * nc1 + cell_of(y, inv1, nc1)) * nc0 + cell_of(x, inv0, nc0)
        new_ids[i] = pid
        rec[gid] = (np.uint64(cb + c) << _KEY) | np.uint64(i)

    @cuda.jit
    def cells(pos, geom, ints, rec):
        """Sort records of positions in global-id order (a state being loaded)."""
        n = ints[3]
        qb = (n + BLOCK - 1) // BLOCK
        r = cuda.blockIdx.x // qb
        local = (cuda.blockIdx.x % qb) * BLOCK + cuda.threadIdx.x
        if local >= n:
            return
        i = r * n + local
        nc0, nc1, nc2 = ints[0], ints[1], ints[2]
        c = cell_of(pos[1, i], geom[1], nc1) * nc0 + cell_of(pos[0, i], geom[0], nc0)
        if DIM == 3:
            c += cell_of(pos[2, i], geom[2], nc2) * nc1 * nc0
        rec[i] = (np.uint64(r * ints[4] + c) << _KEY) | np.uint64(i)

    # -- stable radix sort of the records by cell -------------------------------------

    @cuda.jit(device=True)
    def digit_of(v, shift):
        return np.int64((v >> shift) & MASK)

    @cuda.jit(device=True)
    def block_scan(part, more, tid):
        """Inclusive prefix sums of ``part[:BLOCK]`` and ``more[:BLOCK]`` in place, side
        by side; every thread of the block calls it after writing its entries
        (Hillis-Steele: log2(BLOCK) rounds)."""
        cuda.syncthreads()
        off = 1
        while off < BLOCK:
            v, w = 0, 0
            if tid >= off:
                v, w = part[tid - off], more[tid - off]
            cuda.syncthreads()
            part[tid] += v
            more[tid] += w
            cuda.syncthreads()
            off *= 2

    @cuda.jit
    def digits(rec, hist, m, npass, clock, tick):
        """Count every pass's digits of ``rec[:m]`` into ``hist[p * DIGITS + digit]``
        (zero on entry); with ``tick``, the step counter moves on (the step kernel,
        which reads it, is done)."""
        h = cuda.shared.array(HSIZE, np.int32)
        tid = cuda.threadIdx.x
        if tick and cuda.blockIdx.x == 0 and tid == 0:
            clock[0] += 1
        for e in range(tid, HSIZE, BLOCK):
            h[e] = 0
        cuda.syncthreads()
        first = cuda.blockIdx.x * TILE
        for q in range(ITEMS):
            g = first + q * BLOCK + tid
            if g < m:
                v = rec[g]
                for p in range(npass):
                    cuda.atomic.add(h, p * DIGITS + digit_of(v, _KEY + np.uint64(p * BITS)), 1)
        cuda.syncthreads()
        for e in range(tid, npass * DIGITS, BLOCK):
            if h[e] != 0:
                cuda.atomic.add(hist, e, h[e])

    @cuda.jit
    def scatter(src, dst, m, p, hist, status, tiles, clock):
        """Pass ``p`` of the radix sort, ``src[:m]`` into ``dst``: stable by the digit.

        Tiles are handed out in launch order by ``tiles[p]``. A block loads its tile and
        sorts it stably by the digit in shared memory, half a digit at a time: each thread
        counts its own run of items into its column of ``cnt``, a prefix sum over
        (sub-digit, thread) gives every item its place. It then learns, per digit, how
        many items the tiles before it hold (decoupled look-back: each tile publishes its
        count, then its inclusive prefix, in ``status``, tagged with the sort and pass so
        that nothing needs clearing) and writes each digit's run to ``digit start + items
        of earlier tiles + rank in the tile``."""
        keys = cuda.shared.array(TILE, np.uint64)
        other = cuda.shared.array(TILE, np.uint64)
        cnt = cuda.shared.array(CSIZE, CTYPE)
        part = cuda.shared.array(BLOCK, np.int32)
        more = cuda.shared.array(BLOCK, np.int32)
        tcount = cuda.shared.array(DIGITS, np.int32)
        tstart = cuda.shared.array(DIGITS, np.int32)
        base = cuda.shared.array(DIGITS, np.int64)
        tile_of = cuda.shared.array(1, np.int64)
        tid = cuda.threadIdx.x
        if tid == 0:
            tile_of[0] = cuda.atomic.add(tiles, p, 1)
        if tid < DIGITS:
            tcount[tid] = 0
        for e in range(SUBD):
            cnt[e * BLOCK + tid] = 0
        cuda.syncthreads()
        tile = tile_of[0]
        shift = _KEY + np.uint64(p * BITS)
        first = tile * TILE
        for q in range(ITEMS):
            g = first + q * BLOCK + tid
            v = SENTINEL
            if g < m:
                v = src[g]
                cuda.atomic.add(tcount, digit_of(v, shift), 1)
            keys[q * BLOCK + tid] = v
        cuda.syncthreads()
        # stable sort of the tile by the digit, one half at a time (keys -> other -> keys)
        for sp in range(2):
            a, b = (keys, other) if sp % 2 == 0 else (other, keys)
            sub = shift + np.uint64(sp * SUB)
            for q in range(ITEMS):
                e = np.int64((a[tid * ITEMS + q] >> sub) & SUBMASK) * BLOCK + tid
                cnt[e] += 1
            cuda.syncthreads()
            # exclusive prefix sum of cnt (sub-digit major): each thread a run of SUBD
            total = 0
            for e in range(SUBD):
                total += cnt[tid * SUBD + e]
            part[tid] = total
            more[tid] = 0
            block_scan(part, more, tid)
            acc = part[tid] - total
            for e in range(SUBD):
                v = cnt[tid * SUBD + e]
                cnt[tid * SUBD + e] = acc
                acc += v
            cuda.syncthreads()
            for q in range(ITEMS):  # from here on a thread touches its own column only
                v = a[tid * ITEMS + q]
                e = np.int64((v >> sub) & SUBMASK) * BLOCK + tid
                at = cnt[e]
                cnt[e] = at + 1
                b[at] = v
            for e in range(SUBD):
                cnt[e * BLOCK + tid] = 0
            cuda.syncthreads()
        # where each digit starts in the tile, and in the whole output
        part[tid] = tcount[tid] if tid < DIGITS else 0
        more[tid] = hist[p * DIGITS + tid] if tid < DIGITS else 0
        block_scan(part, more, tid)
        if tid < DIGITS:
            mine = np.int64(tcount[tid])
            tstart[tid] = part[tid] - mine
            # status word: tag (sort and pass, never 0) << 33 | inclusive << 32 | count
            tag = np.int64(1 + (clock[1] * PMAX + p) % (2**30 - 1))
            slot = tile * DIGITS + tid
            before = np.int64(0)
            if tile == 0:
                cuda.atomic.exch(status, slot, (tag << 33) | (np.int64(1) << 32) | mine)
            else:
                cuda.atomic.exch(status, slot, (tag << 33) | mine)
                j = tile - 1
                while j >= 0:
                    w = cuda.atomic.add(status, j * DIGITS + tid, 0)
                    if (w >> 33) != tag:
                        continue  # tile j has not published yet
                    before += w & 0xFFFFFFFF
                    if (w >> 32) & 1:
                        break
                    j -= 1
                cuda.atomic.exch(status, slot, (tag << 33) | (np.int64(1) << 32) | (before + mine))
            base[tid] = np.int64(more[tid]) - hist[p * DIGITS + tid] + before
        cuda.syncthreads()
        for q in range(ITEMS):
            at = q * BLOCK + tid
            v = keys[at]
            d = digit_of(v, shift)
            rank = at - tstart[d]
            if rank < tcount[d]:
                dst[base[d] + rank] = v

    # -- back into slots, cell starts, polar order ------------------------------------

    @cuda.jit(device=True)
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

    @cuda.jit
    def gather(srt, new_pos, new_head, new_ids, new_spd, ints, pos, head, ids, spd, start, partial, bounds):
        """Slot ``s`` takes the particle the sort put there (``srt[s]`` holds the slot it
        came from); each cell's start is found by a binary search in the replica's sorted
        records; each block's sums (float64) go to ``partial``: the heading sum, or with
        extensions the heading sum of each species, then the nematic products (as
        :func:`flocking.observables.moment_sums`)."""
        buf = cuda.shared.array((WIDTH, BLOCK), np.float64)
        n, ncells = ints[3], ints[4]
        qb = (n + BLOCK - 1) // BLOCK
        r = cuda.blockIdx.x // qb
        tid = cuda.threadIdx.x
        local = (cuda.blockIdx.x % qb) * BLOCK + tid
        for a in range(WIDTH):
            buf[a, tid] = 0.0
        if local < n:
            s = r * n + local
            o = np.int64(srt[s] & _LOW)
            row = species_of(new_ids[o], bounds) * DIM
            for a in range(DIM):
                pos[a, s] = new_pos[a, o]
                head[a, s] = new_head[a, o]
                buf[row + a, tid] = np.float64(new_head[a, o])
            if NEM:
                wx, wy = np.float64(new_head[0, o]), np.float64(new_head[1, o])
                row = NSPECIES * DIM
                if DIM == 2:
                    buf[row, tid] = wx * wx - wy * wy
                    buf[row + 1, tid] = 2.0 * wx * wy
                else:
                    wz = np.float64(new_head[2, o])
                    buf[row, tid] = wx * wx
                    buf[row + 1, tid] = wy * wy
                    buf[row + 2, tid] = wz * wz
                    buf[row + 3, tid] = wx * wy
                    buf[row + 4, tid] = wx * wz
                    buf[row + 5, tid] = wy * wz
            ids[s] = new_ids[o]
            if ints[8] != 0:
                spd[s] = new_spd[o]
        if local < ncells:  # cells never outnumber particles
            key = np.uint64(r * ncells + local)
            lo, hi = r * n, r * n + n
            while lo < hi:
                mid = (lo + hi) // 2
                if (srt[mid] >> _KEY) < key:
                    lo = mid + 1
                else:
                    hi = mid
            start[r * ncells + local] = lo
        block_sum(buf, tid)
        if tid == 0:
            for a in range(WIDTH):
                partial[a, cuda.blockIdx.x] = buf[a, 0]

    @cuda.jit
    def finish(partial, ints, phi, clock, hist, tiles, tick):
        """Block ``r``: replica ``r``'s block sums, in a fixed order, into row
        ``clock[0] % rows`` of ``phi`` (with ``tick``). Block 0 also readies the sort's
        counters for the next sort."""
        buf = cuda.shared.array((WIDTH, BLOCK), np.float64)
        n = ints[3]
        qb = (n + BLOCK - 1) // BLOCK
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
                row = clock[0] % ints[9]
                for a in range(WIDTH):
                    phi[r, row, a] = buf[a, 0]

    return types.SimpleNamespace(
        real=real, step=step, cells=cells, digits=digits, scatter=scatter, gather=gather,
        finish=finish, bits=BITS, digits_per_pass=DIGITS, tile=TILE, block=BLOCK, max_passes=PMAX, width=WIDTH,
    )
