"""Topological neighbours, written once: the k nearest others of a particle, by rings of cells.

Plain functions that :func:`flocking.rules.compile` builds for the CPU and CUDA kernels
(constants as in :mod:`flocking.rules.physics`). Particles are kept in cell order:
``start[c]`` is the first slot of cell ``c`` (cells numbered row by row, x fastest, from
``cb``, a replica's first cell), ``pos[a, slot]`` and ``head[a, slot]`` their coordinates
and headings, ``ids[slot]`` their ids. The k best so far live in three arrays of length
``k`` (squared distance, id, slot), nearest first; each offer is one bubble pass over
them with indices fixed by the loop, which a GPU keeps in registers when ``k`` is a
compile-time constant.
"""

import math

from .geometry import cell_number, minimum_image
from .physics import greater, sees

ZERO, INF = 0.0, math.inf
REAL = float

#: the functions of this module that the compiler builds, callees first
RULES = ("lesser", "better", "offer", "knearest")
#: the rules numba inlines into their callers (:func:`flocking.rules.compile` says which)
INLINED = ("better", "offer", "knearest")


def lesser(a, b):
    """``min(a, b)`` as Python's (``a`` unless ``b`` is smaller); CUDA has no builtin."""
    return b if b < a else a


def better(d2, jid, bd, bi, q):
    """Whether a candidate at squared distance ``d2`` with id ``jid`` ranks before entry
    ``q`` of the k best: nearer, or as near with the lower id (an empty entry has id -1
    and distance ``INF``)."""
    if d2 < bd[q]:
        return True
    return d2 == bd[q] and (bi[q] < 0 or jid < bi[q])


def offer(d2, jid, j, bd, bi, bs, k):
    """Put the candidate (``d2``, id ``jid``, slot ``j``) among the ``k`` best if it ranks
    before the last: one pass that carries it down to its place and pushes the others
    back. A NaN distance never ranks."""
    if not better(d2, jid, bd, bi, k - 1):
        return False
    cd, ci, cs = d2, jid, j
    for q in range(k):
        if better(cd, ci, bd, bi, q):
            bd[q], cd = cd, bd[q]
            bi[q], ci = ci, bi[q]
            bs[q], cs = cs, bs[q]
    return True


def knearest(i, c0, c1, c2, cb, pos, head, ids, start, nc0, nc1, nc2, l0, l1, l2, h0, h1, h2, dim, k, with_cone, cone,
             bd, bi, bs):
    """The ``k`` nearest others of slot ``i`` (in cell ``(c0, c1, c2)``) into ``bd``,
    ``bi``, ``bs`` (squared distance, id, slot), nearest first, ties to the lower id;
    returns how many were found. Rings of cells (Chebyshev distance ``r`` in cell
    offsets) are searched outward until the k-th distance is below the distance to any
    unsearched cell. Displacements take the minimum image with half-lengths ``h``
    (``INF`` along walls). With a vision cone (``with_cone``; ``cone`` as in
    :func:`flocking.rules.physics.sees`), only the others inside it are candidates."""
    for q in range(k):
        bd[q] = INF
        bi[q] = -1
        bs[q] = -1
    lo0, lo1 = (nc0 - 1) // 2, (nc1 - 1) // 2
    hi0, hi1 = nc0 - 1 - lo0, nc1 - 1 - lo1
    lo2, hi2 = 0, 0
    if dim == 3:
        lo2 = (nc2 - 1) // 2
        hi2 = nc2 - 1 - lo2
    # distance from the particle to the faces of its own cell, the closest first
    w0, w1, w2 = l0 / REAL(nc0), l1 / REAL(nc1), l2 / REAL(nc2)
    xi, yi = pos[0, i], pos[1, i]
    f = xi - REAL(c0) * w0
    margin = lesser(f, w0 - f)
    f = yi - REAL(c1) * w1
    margin = lesser(margin, lesser(f, w1 - f))
    width = lesser(w0, w1)
    zi = ZERO
    if dim == 3:
        zi = pos[2, i]
        f = zi - REAL(c2) * w2
        margin = lesser(margin, lesser(f, w2 - f))
        width = lesser(width, w2)
    margin = greater(margin, ZERO)
    rmax = greater(greater(lo0, hi0), greater(greater(lo1, hi1), greater(lo2, hi2)))
    found = 0
    r = 0
    while True:
        for o2 in range(-lesser(r, lo2), lesser(r, hi2) + 1):
            g2 = (c2 + o2) % nc2 if dim == 3 else 0
            for o1 in range(-lesser(r, lo1), lesser(r, hi1) + 1):
                g1 = (c1 + o1) % nc1
                edge = abs(o1) == r or abs(o2) == r
                for o0 in range(-lesser(r, lo0), lesser(r, hi0) + 1):
                    if edge or abs(o0) == r:
                        g0 = (c0 + o0) % nc0
                        cell = cb + cell_number(g0, g1, g2, nc0, nc1)
                        for j in range(start[cell], start[cell + 1]):
                            if j == i:
                                continue
                            dx = minimum_image(pos[0, j] - xi, l0, h0)
                            dy = minimum_image(pos[1, j] - yi, l1, h1)
                            d2 = dx * dx + dy * dy
                            a = head[0, i] * dx + head[1, i] * dy
                            if dim == 3:
                                dz = minimum_image(pos[2, j] - zi, l2, h2)
                                d2 += dz * dz
                                a += head[2, i] * dz
                            if with_cone and not sees(a, d2, cone):
                                continue
                            if offer(d2, ids[j], j, bd, bi, bs, k) and found < k:
                                found += 1
        if r >= rmax:
            break
        reach = REAL(r) * width + margin
        if found == k and bd[k - 1] < reach * reach:
            break
        r += 1
    return found
