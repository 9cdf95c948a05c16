"""The CPU backend's step: one family of numba kernels for the plain model and every extension.

:func:`build` compiles the two kernels of a step for one value of
:class:`~flocking.backends.features.Features` (what the model switches on) and a dimension,
from this module's text with the flags as globals, so an extension that is off is not in
the code at all: ``build(Features(), 2)`` is the plain model's step in 2D, and each
extension adds only its own work. The kernels are
thin loops; the physics is :mod:`flocking.rules` compiled for the CPU (``R``).

``lines``
    metric neighbours on a grid of at least three cells per axis: work comes in units of
    :data:`~flocking.backends.cells.SEGMENT` columns of a line of cells, which threads take
    from an atomic counter; a unit gathers its candidates into one buffer
    (:func:`flocking.backends.cells.gather_unit`: periodic images shifted as they are
    copied; across a wall, shifted out of reach), sums every cell of the unit in four SIMD
    lanes, then updates its particles in one loop.
``search``
    topological neighbours (:func:`flocking.rules.neighbours.knearest`), and metric ones
    on a grid with fewer than three cells along some axis (each neighbouring cell visited
    once, every pair by minimum image), over fixed blocks of slots.

Sums. The four lanes of a reduction take candidate ``lo + 4g + l`` into lane ``l`` (a
last, partial group of four is masked by multiplying by 0, never by branching) and are
added in a fixed order: independent chains that LLVM's SLP vectoriser packs into SIMD
registers without reordering any addition, so the result is fixed by this source (never
``fastmath``: its reassociation made freshly compiled and cached kernels round
differently). Without pair weights the sum includes the particle itself and goes to the
update as it is; with them (a coupling, nematic signs, a vision cone, cohesion) each pair
is weighed by :func:`flocking.rules.physics.neighbour`, the particle itself is taken out,
and its own heading goes back with weight 1. Cohesion is summed in a second loop over the
candidates that count, whose displacements the lanes note (:func:`note`, :func:`cohere`).

Determinism. Work units are fixed by the model and a particle's new heading depends only
on the sorted arrays and on counter-based random numbers; each unit's moment sums are
added in slot order and the units in order, so no result depends on the number of
threads. Parameters travel as named tuples: the step's
(:class:`~flocking.backends.features.Step`) and the extensions'
(:class:`~flocking.backends.features.Tables`).
"""

from __future__ import annotations

import functools
import types

import numba
import numpy as np

from ..rules import cached, rebind, source_digest, switch_bits
from ..rules import compile as compile_rules
from . import cells, intrinsics
from .cells import ALL, U1
from .features import NEUTRAL, Features

R = compile_rules("cpu")
U0 = np.uint64(0)
#: a digest of the text compiled into the kernels from other files (the rules, the cell
#: sort, the intrinsics), in their names in numba's cache (:func:`flocking.rules.source_digest`)
SOURCES = source_digest(cells, intrinsics)

# The flags of a variant: what it compiles in (Features, each field in capitals), its
# dimension and its rules: R with its switches, LANES without cohesion (which the lines
# kernel sums apart), RANKED without the cone (the k nearest are ranked among those in it).
# The functions that read them are plain Python here; build() compiles a copy of them per
# variant with the variant's values in place of these.
LANES = RANKED = R
EXTENDED = COUPLING = NEMATIC = CONE = COHESION = WEIGHTED = False
DIM = 2


# -- the plain model's neighbour sums -----------------------------------------------------


@cached(cells, intrinsics, inline="always")
def term_2d(buf, j, last, xi, yi, r2):
    """Candidate ``j``'s heading and 1 if ``j <= last`` and it is within ``R`` of
    ``(xi, yi)``, else zeros (multiplied by 0 or 1, not branched on)."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    w = 1.0 if (dx * dx + dy * dy < r2) & (j <= last) else 0.0
    return buf[2, j] * w, buf[3, j] * w, w


@cached(cells, intrinsics, inline="always")
def term_3d(buf, j, last, xi, yi, zi, r2):
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    dz = buf[2, j] - zi
    w = 1.0 if (dx * dx + dy * dy + dz * dz < r2) & (j <= last) else 0.0
    return buf[3, j] * w, buf[4, j] * w, buf[5, j] * w, w


@cached(cells, intrinsics)
def reduce_2d(buf, ranges, x, y, i0, i1, r2, out, o):
    """For slots ``i0..i1``: the sum of the headings and the count of the candidates in
    ``ranges`` of the buffer within ``R`` (the particle itself included), into
    ``out[:, o + i - i0]``."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        n0 = n1 = n2 = n3 = 0.0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = ALL if j < m4 else hi - U1
                p0, q0, w0 = term_2d(buf, j, last, xi, yi, r2)
                p1, q1, w1 = term_2d(buf, j + U1, last, xi, yi, r2)
                p2, q2, w2 = term_2d(buf, j + np.uint64(2), last, xi, yi, r2)
                p3, q3, w3 = term_2d(buf, j + np.uint64(3), last, xi, yi, r2)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (n0 + n1) + (n2 + n3)


@cached(cells, intrinsics)
def reduce_3d(buf, ranges, x, y, z, i0, i1, r2, out, o):
    """As :func:`reduce_2d`, in 3D."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        zi = z[i]
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        c0 = c1 = c2 = c3 = 0.0
        n0 = n1 = n2 = n3 = 0.0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = ALL if j < m4 else hi - U1
                p0, q0, r0, w0 = term_3d(buf, j, last, xi, yi, zi, r2)
                p1, q1, r1, w1 = term_3d(buf, j + U1, last, xi, yi, zi, r2)
                p2, q2, r2_, w2 = term_3d(buf, j + np.uint64(2), last, xi, yi, zi, r2)
                p3, q3, r3, w3 = term_3d(buf, j + np.uint64(3), last, xi, yi, zi, r2)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                c0, c1, c2, c3 = c0 + r0, c1 + r1, c2 + r2_, c3 + r3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (c0 + c1) + (c2 + c3)
        out[3, o + i - i0] = (n0 + n1) + (n2 + n3)


# -- weighted neighbour sums (pair weights, cohesion) ---------------------------------------


# How many of a group's four candidates count, for each 4-bit mask of them (bit l: candidate
# l counts). The mask is the lanes' vector comparison taken whole (intrinsics.mask4, one move).
COUNT = np.array([bin(m).count("1") for m in range(16)], dtype=np.uint64)


@cached(cells, intrinsics, inline="always")
def note(near, k, row, v0, v1, v2, v3, w0, w1, w2, w3):
    """Write those of ``v0 .. v3`` whose count ``w`` is not 0 to ``near[row]`` from
    ``near[row, k]`` on, in order, then zeros (``near[row, k .. k + 3]`` are written
    whatever counts): returns the new ``k``. The lanes note each coordinate of a group's
    displacements so, in one vector store (:data:`flocking.backends.intrinsics.compress4`).

    >>> near = np.full((1, 8), 9.0)
    >>> k = note(near, U0, 0, 0.5, 0.0, -1.5, 2.0, 1.0, 0.0, 1.0, 1.0)
    >>> int(k), near[0].tolist()
    (3, [0.5, -1.5, 2.0, 0.0, 9.0, 9.0, 9.0, 9.0])
    """
    t = intrinsics.compress4(v0, v1, v2, v3, w0 != 0.0, w1 != 0.0, w2 != 0.0, w3 != 0.0)
    near[row, k] = t[0]
    near[row, k + U1] = t[1]
    near[row, k + np.uint64(2)] = t[2]
    near[row, k + np.uint64(3)] = t[3]
    return k + COUNT[intrinsics.mask4(w0 != 0.0, w1 != 0.0, w2 != 0.0, w3 != 0.0)]


# These read the flags (COUPLING, NEMATIC, CONE, COHESION) as globals: compiled per variant
# by build() and inlined into its kernels, what a flag leaves out is never compiled.


def pair_2d(buf, j, last, xi, yi, ux, uy, r2, jr, pv):
    """Candidate ``j`` of the buffer by :func:`flocking.rules.physics.neighbour` as the
    lanes take it (``LANES``: without cohesion, see :func:`wreduce_2d`; ``pv`` the pair
    terms' values): it counts within ``R`` and ``j <= last``; the coupling of the
    particle's species to the candidate's is buffer row ``jr``. Returns the weighed
    heading (2), the count and the displacement (2)."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    d2 = dx * dx + dy * dy
    t = LANES.neighbour(2, dx, dy, 0.0, d2, (d2 < r2) & (j <= last), ux, uy, 0.0, buf[2, j], buf[3, j], 0.0,
                        buf[jr, j] if COUPLING else 1.0, pv)
    return t[0], t[1], t[3], dx, dy


def pair_3d(buf, j, last, xi, yi, zi, ux, uy, uz, r2, jr, pv):
    """:func:`pair_2d` in 3D: the weighed heading (3), the count, the displacement (3)."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    dz = buf[2, j] - zi
    d2 = dx * dx + dy * dy + dz * dz
    t = LANES.neighbour(3, dx, dy, dz, d2, (d2 < r2) & (j <= last), ux, uy, uz, buf[3, j], buf[4, j], buf[5, j],
                        buf[jr, j] if COUPLING else 1.0, pv)
    return t[0], t[1], t[2], t[3], dx, dy, dz


def cohere(near, k, pv, sums, out, q):
    """Cohesion of a particle: :func:`flocking.rules.physics.cohesion_term` of the ``k``
    displacements noted in ``near`` (a row per coordinate), summed in four lanes as the
    reductions sum (lane ``l`` takes terms ``l, l + 4, ...``), into rows ``DIM + 1`` on
    of ``out[:, q]``: the pull (``DIM``), the push (``DIM``), the core count.

    The lanes' running sums are kept in ``sums``, a row per quantity: entry ``p + 4`` is
    entry ``p`` plus term ``p``. An entry depends only on the one four before it, so LLVM
    vectorises the loop four terms at a time, square roots and divisions included,
    without reordering any addition; the last group's missing terms are zeros, weighed by
    0 (``inside`` false). ``pv``: the pair terms' values."""
    d = DIM
    u4 = np.uint64(4)
    for r in range(d):
        near[r, k] = near[r, k + U1] = near[r, k + np.uint64(2)] = 0.0
    for r in range(2 * d + 1):
        sums[r, 0] = sums[r, 1] = sums[r, 2] = sums[r, 3] = 0.0
    k4 = (k + np.uint64(3)) & ~np.uint64(3)
    for p in range(U0, k4):
        dx = near[0, p]
        dy = near[1, p]
        dz = near[2, p] if d == 3 else 0.0
        t = R.cohesion_term(dx, dy, dz, dx * dx + dy * dy + dz * dz, p < k, pv)
        sums[0, p + u4] = sums[0, p] + t[0]
        sums[1, p + u4] = sums[1, p] + t[1]
        sums[d, p + u4] = sums[d, p] + t[3]
        sums[d + 1, p + u4] = sums[d + 1, p] + t[4]
        if d == 3:
            sums[2, p + u4] = sums[2, p] + t[2]
            sums[5, p + u4] = sums[5, p] + t[5]
        sums[2 * d, p + u4] = sums[2 * d, p] + t[6]
    k1, k2, k3 = k4 + U1, k4 + np.uint64(2), k4 + np.uint64(3)
    for r in range(2 * d + 1):
        out[d + 1 + r, q] = (sums[r, k4] + sums[r, k1]) + (sums[r, k2] + sums[r, k3])


# The weighed sums keep one scalar per lane and quantity, like the plain ones: held in
# tuples, the lanes were not packed into SIMD registers (three times slower per candidate).
# Cohesion is not summed in the lanes: they note the displacements of the candidates that
# count (``near``: :func:`note`, a group of four at a time, no branch), and :func:`cohere`
# sums over those alone: its square root, division and piecewise force for the few within
# reach, not for every candidate, and no more registers in the lanes.


def wreduce_2d(buf, ranges, x, y, hx, hy, tag, i0, i1, r2, pv, near, sums, out, o):
    """As :func:`reduce_2d` (the particle itself included, four lanes), each candidate
    weighed by :func:`pair_2d`; rows of ``out``: the heading sum (2), the count, and with
    cohesion (:func:`cohere`, ``near`` and ``sums`` its scratch) the pull (2), the push
    (2) and the core count."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        ux = hx[i]
        uy = hy[i]
        jr = np.uint64(4 + int(tag[i])) if COUPLING else np.uint64(0)
        a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = n0 = n1 = n2 = n3 = 0.0
        k = U0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = ALL if j < m4 else hi - U1
                p0, q0, w0, x0, y0 = pair_2d(buf, j, last, xi, yi, ux, uy, r2, jr, pv)
                p1, q1, w1, x1, y1 = pair_2d(buf, j + U1, last, xi, yi, ux, uy, r2, jr, pv)
                p2, q2, w2, x2, y2 = pair_2d(buf, j + np.uint64(2), last, xi, yi, ux, uy, r2, jr, pv)
                p3, q3, w3, x3, y3 = pair_2d(buf, j + np.uint64(3), last, xi, yi, ux, uy, r2, jr, pv)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
                if COHESION:
                    note(near, k, 0, x0, x1, x2, x3, w0, w1, w2, w3)
                    k = note(near, k, 1, y0, y1, y2, y3, w0, w1, w2, w3)
        q = o + i - i0
        out[0, q] = (a0 + a1) + (a2 + a3)
        out[1, q] = (b0 + b1) + (b2 + b3)
        out[2, q] = (n0 + n1) + (n2 + n3)
        if COHESION:
            cohere(near, k, pv, sums, out, q)


def wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, pv, near, sums, out, o):
    """:func:`wreduce_2d` in 3D; rows: heading sum (3), count, pull (3), push (3), core count."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        zi = z[i]
        ux = hx[i]
        uy = hy[i]
        uz = hz[i]
        jr = np.uint64(6 + int(tag[i])) if COUPLING else np.uint64(0)
        a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = c0 = c1 = c2 = c3 = n0 = n1 = n2 = n3 = 0.0
        k = U0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = ALL if j < m4 else hi - U1
                j1, j2, j3 = j + U1, j + np.uint64(2), j + np.uint64(3)
                p0, q0, r0, w0, x0, y0, z0 = pair_3d(buf, j, last, xi, yi, zi, ux, uy, uz, r2, jr, pv)
                p1, q1, r1, w1, x1, y1, z1 = pair_3d(buf, j1, last, xi, yi, zi, ux, uy, uz, r2, jr, pv)
                p2, q2, r2_, w2, x2, y2, z2 = pair_3d(buf, j2, last, xi, yi, zi, ux, uy, uz, r2, jr, pv)
                p3, q3, r3, w3, x3, y3, z3 = pair_3d(buf, j3, last, xi, yi, zi, ux, uy, uz, r2, jr, pv)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                c0, c1, c2, c3 = c0 + r0, c1 + r1, c2 + r2_, c3 + r3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
                if COHESION:
                    note(near, k, 0, x0, x1, x2, x3, w0, w1, w2, w3)
                    note(near, k, 1, y0, y1, y2, y3, w0, w1, w2, w3)
                    k = note(near, k, 2, z0, z1, z2, z3, w0, w1, w2, w3)
        q = o + i - i0
        out[0, q] = (a0 + a1) + (a2 + a3)
        out[1, q] = (b0 + b1) + (b2 + b3)
        out[2, q] = (c0 + c1) + (c2 + c3)
        out[3, q] = (n0 + n1) + (n2 + n3)
        if COHESION:
            cohere(near, k, pv, sums, out, q)


@cached(cells, intrinsics, inline="always")
def species(pid, bounds):
    """:func:`flocking.rules.physics.species_of` with as many species as ``bounds`` has
    ranges (the CPU kernels are not compiled per count of species)."""
    return R.species_of(pid, bounds, bounds.shape[0] - 1)


# -- the sums of the search kernel --------------------------------------------------------


def pair_terms(i, j, dx, dy, dz, d2, inside, pos, head, ids, tb, si):
    """Neighbour candidate ``j`` of slot ``i`` at ``r = (dx, dy, dz)`` by
    :func:`flocking.rules.physics.neighbour` (``si``: the species of ``i``; ``d``: the
    dimension, a constant of the kernel). Compiled twice per variant: with the variant's
    rules (``R``), and as ``ranked_terms`` with the cone left out (``RANKED``) for the k
    nearest, which are ranked among those in the cone."""
    d = DIM
    coupling = tb.coupling[si, species(ids[j], tb.bounds)] if COUPLING else 1.0
    return R.neighbour(d, dx, dy, dz, d2, inside, head[0, i], head[1, i], head[2, i] if d == 3 else 0.0, head[0, j],
                       head[1, j], head[2, j] if d == 3 else 0.0, coupling, R.pair_values(tb.pair))


#: :func:`pair_terms` with the cone left out, for the k nearest: compiled per variant with ``RANKED``
ranked_terms = pair_terms


def metric_sums(i, c, pos, head, ids, start, nc, box, r2, tb, si):
    """Slot ``i``'s sums over the cells around its own cell ``c``, each cell once, every
    pair by minimum image, none across a wall: ``(S (3), count, pull (3), push (3), core
    count)``; ``S`` and the count include the particle itself unless ``WEIGHTED``."""
    d = DIM
    c0, c1, c2 = R.cell_coords(c, nc[0], nc[1])
    o0, n0 = cells.axis_cells(c0, nc[0])
    o1, n1 = cells.axis_cells(c1, nc[1])
    o2, n2 = 0, 1
    if d == 3:
        o2, n2 = cells.axis_cells(c2, nc[2])
    s = R.SUM0
    for k2 in range(n2):
        g2 = o2 + k2
        if d == 3:
            if EXTENDED and tb.walls[2] != 0 and (g2 < 0 or g2 >= nc[2]):
                continue
            g2 %= nc[2]
        for k1 in range(n1):
            g1 = o1 + k1
            if EXTENDED and tb.walls[1] != 0 and (g1 < 0 or g1 >= nc[1]):
                continue
            g1 %= nc[1]
            for k0 in range(n0):
                g0 = o0 + k0
                if EXTENDED and tb.walls[0] != 0 and (g0 < 0 or g0 >= nc[0]):
                    continue
                g0 %= nc[0]
                cell = R.cell_number(g0, g1, g2, nc[0], nc[1])
                for j in range(start[cell], start[cell + 1]):
                    if WEIGHTED and j == i:
                        continue
                    dx = R.minimum_image(pos[0, j] - pos[0, i], box[0], tb.half[0])
                    dy = R.minimum_image(pos[1, j] - pos[1, i], box[1], tb.half[1])
                    d2 = dx * dx + dy * dy
                    dz = 0.0
                    if d == 3:
                        dz = R.minimum_image(pos[2, j] - pos[2, i], box[2], tb.half[2])
                        d2 += dz * dz
                    t = pair_terms(i, j, dx, dy, dz, d2, d2 < r2, pos, head, ids, tb, si)
                    if t[3] != 0.0:  # only what counts is added, as the reference adds it
                        s = R.plus(s, t)
    if WEIGHTED:  # the count includes the particle itself
        s = R.counted(s)
    return s


def nearest_sums(i, c, pos, head, ids, start, nc, box, k, tb, si, bd, bi, bs):
    """As :func:`metric_sums`, over the ``k`` nearest others (in rank order, nearest
    first; the particle itself first unless ``WEIGHTED``)."""
    d = DIM
    nc2 = nc[2] if d == 3 else 1
    l2 = box[2] if d == 3 else 1.0
    h2 = tb.half[2] if d == 3 else np.inf
    c0, c1, c2 = R.cell_coords(c, nc[0], nc[1])
    found = R.knearest(i, c0, c1, c2, 0, pos, head, ids, start, nc[0], nc[1], nc2, box[0], box[1], l2, tb.half[0],
                       tb.half[1], h2, d, k, CONE, R.cone_of(R.pair_values(tb.pair)), bd, bi, bs)
    s = R.SUM0
    if not WEIGHTED:
        s = (head[0, i], head[1, i], head[2, i] if d == 3 else 0.0) + R.SUM0[3:]
    for q in range(found):
        j = bs[q]
        dx = dy = dz = 0.0
        if COHESION:
            dx = R.minimum_image(pos[0, j] - pos[0, i], box[0], tb.half[0])
            dy = R.minimum_image(pos[1, j] - pos[1, i], box[1], tb.half[1])
            if d == 3:
                dz = R.minimum_image(pos[2, j] - pos[2, i], box[2], tb.half[2])
        s = R.plus(s, ranked_terms(i, j, dx, dy, dz, bd[q], True, pos, head, ids, tb, si))
    return s[:3] + (float(found + 1),) + s[4:]


# -- one particle's step ------------------------------------------------------------------


def advance(i, s, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed, p, nc, inv, box, tb):
    """Slot ``i``'s new heading and position into ``new_*[:, i]`` and its new cell into
    ``cell[i]``, from its sums ``s`` (:data:`flocking.rules.step.SUMS`: with ``WEIGHTED``,
    the others' weighed headings, else the sum with itself; ``p``: the step's parameters);
    returns the new heading (``wz`` is 0 in 2D). The delay's ring first, then the step's
    end as both backends take it (:func:`flocking.rules.step.finish`)."""
    d = DIM
    n = pos.shape[1]
    pid = ids[i]
    ux, uy = head[0, i], head[1, i]
    uz = head[2, i] if d == 3 else 0.0
    if p.delay > 0:
        # ring rows are read by particle id, in no particular order: ask for the row a few
        # particles ahead so that its cache miss overlaps work
        intrinsics.prefetch(ring, slot, ids[min(np.int64(i) + 4, n - 1)])
        if not WEIGHTED:  # the ring holds the others' sum
            s = R.with_own(s, -1.0, ux, uy, uz)
        past = R.recall(ring, slot, pid, d, COHESION)
        R.keep(ring, slot, pid, s, d, COHESION)
        s = R.with_own(past, 1.0, ux, uy, uz)
    elif WEIGHTED:
        s = R.with_own(s, 1.0, ux, uy, uz)
    if EXTENDED:
        si = species(pid, tb.bounds)
        eta, epsilon, h = tb.species[si, 0], tb.species[si, 1], tb.species[si, 4]
        cturn, sturn = tb.species[si, 2], tb.species[si, 3]
    else:
        eta, epsilon, h, cturn, sturn = p.eta, p.epsilon, 0.0, 1.0, 0.0
    ds = (spd[i] if spd.shape[0] == n else spd[0]) * p.dt
    z, l2, h2, w2 = 0.0, 1.0, np.inf, False  # the third axis, read apart: a conditional among the
    # call's arguments is control flow that numba cannot inline
    if d == 3:
        z, l2, h2, w2 = pos[2, i], box[2], tb.half[2], tb.walls[2] != 0
    x, y, z, wx, wy, wz = R.finish(d, EXTENDED, COHESION, ux, uy, uz, s, tb.beta[0], (eta, epsilon, h, cturn, sturn),
                                   p.vectorial, p.backward, seed, step, pid, (tb.field[0], tb.field[1], tb.field[2]),
                                   ds, pos[0, i], pos[1, i], z, (box[0], box[1], l2), (tb.half[0], tb.half[1], h2),
                                   (tb.walls[0] != 0, tb.walls[1] != 0, w2), tb.obstacles, tb.obstacles.shape[0])
    new_pos[0, i], new_pos[1, i] = x, y
    new_head[0, i], new_head[1, i] = wx, wy
    if d == 3:
        new_pos[2, i] = z
        new_head[2, i] = wz
    cell[i] = cells.cell_of(new_pos, i, nc, inv)
    return wx, wy, wz


def add_moments(acc, wx, wy, wz, pid, bounds):
    """Slot's new heading into the moment sums ``acc`` (one column) by
    :func:`flocking.rules.step.add_moments`: its species from ``bounds``, and the nematic
    products where ``acc`` has rows for them (a variant with nematic alignment compiled in
    also runs models without it)."""
    count = bounds.shape[0] - 1
    R.add_moments(acc, 0, pid, bounds, count, DIM, NEMATIC and acc.shape[0] > count * DIM, wx, wy, wz)


# -- the kernels --------------------------------------------------------------------------


def lines(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params, partial,
          threads, tb):
    n = pos.shape[1]
    nt = max(1, min(threads, cells.work_units(nc, n, 0)))
    # per slot its species and its coupling from each species: a unit's buffer holds the
    # latter as rows, so a weighed sum reads one row instead of a look-up per pair
    tag = np.empty(n if COUPLING else 0)
    cols = np.empty((tb.coupling.shape[0] if COUPLING else 0, n))
    if COUPLING:
        for i in numba.prange(n):
            s = species(ids[i], tb.bounds)
            tag[i] = s
            for a in range(cols.shape[0]):
                cols[a, i] = tb.coupling[a, s]
    counter = np.zeros(1, dtype=np.int64)
    for t in numba.prange(nt):
        line_units(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
                   partial, tb, tag, cols, counter)


def line_units(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
               partial, tb, tag, cols, counter):
    """One thread's share of :func:`lines`: units of work taken from ``counter`` until none
    is left (``tag``, ``cols``: the species and the coupling columns of the slots). Inlined
    into the parallel loop: called from it as a function of its own, it ran at 0.6 to 0.85 of
    the speed (2D, N = 1e5)."""
    d = DIM
    n = pos.shape[1]
    r2 = params.r2
    pv = R.pair_values(tb.pair)  # in registers: read once, not per pair
    inv = nc / box
    shifts = tb.shifts if EXTENDED else box  # what a periodic image is shifted by (2L across a wall)
    nx = nc[0]
    nseg = (nx + cells.SEGMENT - 1) // cells.SEGMENT
    nunits = cells.work_units(nc, n, 0)
    # views taken once per thread: a view in the hot loop costs an atomic refcount
    x, y, z = pos[0], pos[1], pos[d - 1]
    hx, hy, hz = head[0], head[1], head[d - 1]
    buf = np.empty((2 * d + cols.shape[0], 4096))
    rows = np.empty((3 if d == 2 else 9, 4), dtype=np.int64)
    ranges = np.empty((3 if d == 2 else 9, 2), dtype=np.int64)
    out = np.empty((4 if not COHESION else 12, 16))  # rows of the per-slot sums
    near = np.empty((d, buf.shape[1] + 4 if COHESION else 0))  # wreduce_*'s scratch: noted displacements
    sums = np.empty((2 * d + 1, near.shape[1] + 4))  # and cohesion's running sums
    acc = np.zeros((partial.shape[1], 1))
    while True:
        # units go to whichever thread is free: balanced when particles cluster or
        # when another program holds a core; a unit's result never depends on who
        u = intrinsics.fetch_add(counter)
        if u >= nunits:
            break
        if COUPLING:
            gy, gz, c0, c1, s0, s1, buf, out = cells.gather_unit(u, nseg, x, y, z, hx, hy, hz, cols, start, nc,
                                                                   shifts, buf, rows, out, d)
        else:
            gy, gz, c0, c1, s0, s1, buf, out = cells.gather_unit(u, nseg, x, y, z, hx, hy, hz, None, start, nc,
                                                                   shifts, buf, rows, out, d)
        if COHESION and near.shape[1] < buf.shape[1] + 4:
            near = np.empty((d, buf.shape[1] + 4))
            sums = np.empty((2 * d + 1, near.shape[1] + 4))
        # first the sums of every particle of the segment, then the updates in one
        # loop: its iterations are independent, so the processor overlaps their long
        # chains of dependent operations (it cannot across the reductions)
        for cx in range(c0, c1):
            c = R.cell_number(cx, gy, gz, nx, nc[1])
            cells.candidate_ranges(cx, nx, start, rows, ranges)
            if not WEIGHTED and d == 2:
                reduce_2d(buf, ranges, x, y, start[c], start[c + 1], r2, out, start[c] - s0)
            elif not WEIGHTED:
                reduce_3d(buf, ranges, x, y, z, start[c], start[c + 1], r2, out, start[c] - s0)
            elif d == 2:
                wreduce_2d(buf, ranges, x, y, hx, hy, tag, start[c], start[c + 1], r2, pv, near, sums, out,
                           start[c] - s0)
            else:
                wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, start[c], start[c + 1], r2, pv, near, sums,
                           out, start[c] - s0)
        px = 0.0
        py = 0.0
        pz = 0.0
        if EXTENDED:
            acc[:] = 0.0
        # unsigned slots: no negative-index wraparound on every access
        for i in range(np.uint64(max(s0, 0)), np.uint64(max(s1, 0))):
            q = np.int64(i) - s0
            sz = out[2, q] if d == 3 else 0.0
            s = (out[0, q], out[1, q], sz, out[d, q]) + R.SUM0[4:]
            if COHESION:
                o = d + 1
                s = s[:4] + (out[o, q], out[o + 1, q], out[o + 2, q] if d == 3 else 0.0, out[o + d, q],
                             out[o + d + 1, q], out[o + d + 2, q] if d == 3 else 0.0, out[o + 2 * d, q])
            if WEIGHTED:
                # the sums include the particle itself, with its own species'
                # coupling, in its cone, of its own sense: take it out
                w = tb.coupling[int(tag[i]), int(tag[i])] if COUPLING else 1.0
                s = R.with_own(s, -w, hx[i], hy[i], hz[i] if d == 3 else 0.0)
            wx, wy, wz = advance(i, s, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed,
                                 params, nc, inv, box, tb)
            if EXTENDED:
                add_moments(acc, wx, wy, wz, ids[i], tb.bounds)
            else:
                px += wx
                py += wy
                pz += wz
        if EXTENDED:
            partial[u, :] = acc[:, 0]
        else:
            partial[u, 0] = px
            partial[u, 1] = py
            partial[u, 2] = pz


def search(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params, partial,
           threads, tb):
    nt = max(1, min(threads, cells.work_units(nc, pos.shape[1], 1)))
    counter = np.zeros(1, dtype=np.int64)
    for t in numba.prange(nt):
        search_blocks(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
                      partial, tb, counter)


def search_blocks(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
                  partial, tb, counter):
    """One thread's share of :func:`search`: blocks of slots taken from ``counter`` until
    none is left."""
    n = pos.shape[1]
    k = params.k
    r2 = params.r2
    inv = nc / box
    ncells = start.shape[0] - 1
    nblocks = cells.work_units(nc, n, 1)
    bd = np.empty(max(k, 1))
    bi = np.empty(max(k, 1), dtype=np.int64)
    bs = np.empty(max(k, 1), dtype=np.int64)
    acc = np.zeros((partial.shape[1], 1))
    while True:
        b = intrinsics.fetch_add(counter)
        if b >= nblocks:
            break
        s0 = b * cells.BLOCK
        s1 = min(n, s0 + cells.BLOCK)
        c = np.searchsorted(start, s0, side="right") - 1
        px = 0.0
        py = 0.0
        pz = 0.0
        if EXTENDED:
            acc[:] = 0.0
        while c < ncells and start[c] < s1:
            for i in range(max(start[c], s0), min(start[c + 1], s1)):
                si = species(ids[i], tb.bounds) if COUPLING else 0
                if k == 0:
                    s = metric_sums(i, c, pos, head, ids, start, nc, box, r2, tb, si)
                else:
                    s = nearest_sums(i, c, pos, head, ids, start, nc, box, k, tb, si, bd, bi, bs)
                wx, wy, wz = advance(i, s, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed,
                                     params, nc, inv, box, tb)
                if EXTENDED:
                    add_moments(acc, wx, wy, wz, ids[i], tb.bounds)
                else:
                    px += wx
                    py += wy
                    pz += wz
            c += 1
        if EXTENDED:
            partial[b, :] = acc[:, 0]
        else:
            partial[b, 0] = px
            partial[b, 1] = py
            partial[b, 2] = pz


#: the functions compiled once per variant, callees first: each reads the flags as globals
VARIANT = ("pair_2d", "pair_3d", "cohere", "wreduce_2d", "wreduce_3d", "pair_terms", "metric_sums",
           "nearest_sums", "advance", "add_moments", "line_units", "search_blocks")


def variant(features: Features, kernel: str) -> Features:
    """The variant of ``kernel`` (``lines`` or ``search``) that steps a model with
    ``features``. In ``lines`` each pair weight is compiled in only for a model that has it:
    there a weight costs even when neutral (with nematic alignment compiled in, a model with
    a cone ran at 0.79 of the plain rate instead of 0.87, and with a coupling compiled in at
    0.73 instead of 0.89; docs/performance.md). In ``search``, which looks the coupling up
    per pair, they are compiled in together whichever is on (a cone ran at 0.78 to 0.80 of
    the plain rate either way), so that a new combination seldom waits for numba: the ones a
    model leaves off are made neutral by their tables (a ``bias`` of 4, the cone -4,
    couplings of 1) and multiply by exactly 1, so the sums are those of a variant of its
    own, bit for bit. Cohesion keeps variants of its own (with the weights compiled in it
    ran at 0.35 of the plain rate instead of 0.50, measured before it had a pass of its own).

    >>> variant(Features(extended=True, cone=True), "lines") == Features(extended=True, cone=True)
    True
    >>> variant(Features(extended=True, coupling=True), "search")
    Features(extended=True, coupling=True, nematic=True, cone=True, cohesion=False)
    >>> variant(Features(extended=True, cohesion=True), "search") == Features(extended=True, cohesion=True)
    True
    """
    if kernel == "lines" or not any(getattr(features, weight) for weight in NEUTRAL):
        return features
    return features._replace(**{weight: True for weight in NEUTRAL})


def cache_tag(features: Features, dim: int) -> str:
    """What names the kernels :func:`build` compiles for ``features`` in ``dim`` dimensions
    in numba's cache: the dimension and a bit per feature.

    >>> cache_tag(Features(extended=True, cohesion=True), 2)
    '2d_10001'
    """
    return f"{dim}d_" + switch_bits(features)


@functools.lru_cache(maxsize=None)
def build(features: Features, dim: int) -> types.SimpleNamespace:
    """The step kernels for ``features`` in ``dim`` dimensions: ``lines`` and ``search``,
    each called as
    ``kernel(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step,
    seed, params, partial, threads, tables)``: one step from the sorted arrays into
    ``new_*`` (same slots), each slot's new cell into ``cell``, unit ``u``'s moment sums
    into ``partial[u]``; ``params`` is the model's :class:`~flocking.backends.features.Step`,
    ``tables`` its :class:`~flocking.backends.features.Tables`;
    ``threads`` only splits the work. Units of work: :func:`flocking.backends.cells.work_units`
    (mode 0 for ``lines``, 1 for ``search``).

    The functions of :data:`VARIANT` and the two kernels are compiled from their text here
    with the variant's flags as globals (as :func:`flocking.rules.compile` binds the
    rules' constants): numba folds a branch on a global before it inlines what the branch
    calls, so code that a flag leaves out is never compiled, which keeps a variant's
    compilation short. The kernels are cached on disk under a name of their own and
    :data:`SOURCES`.
    """
    namespace, tag = variant_namespace(features, dim), cache_tag(features, dim)
    kernels = {name: numba.njit(cache=True, parallel=True)(rebind(globals()[name], namespace,
                                                                  f"{name}_{tag}_{SOURCES}"))
               for name in ("lines", "search")}
    return types.SimpleNamespace(**kernels, features=features)


@functools.lru_cache(maxsize=None)
def variant_namespace(features: Features, dim: int) -> dict:
    """The globals :func:`build` compiles a variant's kernels with: its flags, and the
    functions of :data:`VARIANT` compiled with them (another kernel that reuses them,
    :mod:`flocking.backends.cpu_graph`, is compiled with the same)."""
    namespace = {**globals(), **features.flags(), "WEIGHTED": features.weighted, "DIM": dim,
                 "R": compile_rules("cpu", switches=features),
                 "LANES": compile_rules("cpu", switches=features._replace(cohesion=False)),
                 "RANKED": compile_rules("cpu", switches=features._replace(cone=False))}
    ranked = {**namespace, "R": namespace["RANKED"]}
    namespace["ranked_terms"] = numba.njit(inline="always")(rebind(pair_terms, ranked, "ranked_terms"))
    for name in VARIANT:
        namespace[name] = numba.njit(inline="always")(rebind(globals()[name], namespace))
    return namespace

