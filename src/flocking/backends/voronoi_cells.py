"""Voronoi neighbours in 2D by each particle's own cell, in parallel over the cell list.

A particle's Voronoi cell is the intersection of half-planes: ``x`` at least as near to it as
to each other particle. :func:`cell_neighbours` starts from the rectangle the particle's own
periodic images bound (``L/2`` either side) or the walls bound, and cuts it by the bisector
of every candidate in its cell, then in the rings of cells around it, as Voro++ does. After
ring ``r`` every particle within ``r h`` is seen (``h`` the cell's smaller side); once the
cell's farthest vertex is at ``rho`` with ``2 rho <= r h``, no particle not seen can cut it
(a bisector cuts only within ``rho`` of the particle when the other is within ``2 rho``):
the cell is exact. Its sides longer than ``TIE`` mean spacings
(:data:`flocking.backends.delaunay.TIE`) name its neighbours; the lists are made
symmetric and sorted by :func:`flocking.backends.delaunay.compress`.

Each cell is cut on its own, by one thread, from the sorted arrays: the answer does not
depend on the number of threads. :func:`graph` gives ``None`` (the caller then triangulates,
:mod:`flocking.backends.delaunay`) when coincident particles are present, when a cell
would need a ring that wraps around a periodic box (fewer than ``2 r + 1`` cells), or when
a cell has more than :data:`MAX_SIDES` sides.
"""

from __future__ import annotations

import numba
import numpy as np

from ..rules import cached
from ..rules import compile as compile_rules
from . import cells, delaunay

R = compile_rules("cpu")

#: most sides a cell may have (a random state's have 4 to about 12)
MAX_SIDES = 48


@cached(cells, delaunay, inline="always")
def cut(px, py, tag, m, qx, qy, qtag, ax, ay, j):
    """Cut the convex polygon ``px, py`` (``m`` vertices; side ``k`` from vertex ``k`` to
    ``k + 1`` made by ``tag[k]``) by ``a . x <= |a|^2 / 2``, the bisector of particle ``j``
    at ``a`` from the origin; into ``qx, qy, qtag``: returns the new count."""
    h = 0.5 * (ax * ax + ay * ay)
    out = 0
    for k in range(m):
        k1 = k + 1 if k + 1 < m else 0
        va = ax * px[k] + ay * py[k] - h
        vb = ax * px[k1] + ay * py[k1] - h
        if va <= 0.0:
            qx[out], qy[out], qtag[out] = px[k], py[k], tag[k]
            out += 1
        if (va <= 0.0) != (vb <= 0.0):
            t = va / (va - vb)
            qx[out] = px[k] + t * (px[k1] - px[k])
            qy[out] = py[k] + t * (py[k1] - py[k])
            qtag[out] = j if va <= 0.0 else tag[k]
            out += 1
    return out


@cached(cells, delaunay)
def cell_neighbours(i, pos, start, nc, box, walls, tol, px, py, tag, qx, qy, qtag, found):
    """Particle (slot) ``i``'s Voronoi neighbours into ``found``: returns their count, or
    -1 when the cell cannot be made here (see the module's docstring)."""
    xi, yi = pos[0, i], pos[1, i]
    hx, hy = box[0] / nc[0], box[1] / nc[1]
    step = min(hx, hy)
    c0 = cells.cell_of(pos, i, nc, nc / box)  # the cell the sort put it in
    gx, gy, _ = R.cell_coords(c0, nc[0], nc[1])
    half_x = R.reach(box[0], walls[0])  # the minimum image's reach (none across walls)
    half_y = R.reach(box[1], walls[1])
    lo_x, hi_x = (-xi, box[0] - xi) if walls[0] else (-half_x, half_x)
    lo_y, hi_y = (-yi, box[1] - yi) if walls[1] else (-half_y, half_y)
    px[0], py[0], px[1], py[1] = lo_x, lo_y, hi_x, lo_y
    px[2], py[2], px[3], py[3] = hi_x, hi_y, lo_x, hi_y
    tag[0] = tag[1] = tag[2] = tag[3] = -1
    m = 4
    rho2 = max(lo_x * lo_x, hi_x * hi_x) + max(lo_y * lo_y, hi_y * hi_y)
    r = 0
    while True:
        if (not walls[0] and 2 * r + 1 > nc[0]) or (not walls[1] and 2 * r + 1 > nc[1]):
            return -1
        for oy in range(-r, r + 1):
            cy = gy + oy
            if walls[1] and (cy < 0 or cy >= nc[1]):
                continue
            cy %= nc[1]
            ring_row = oy == -r or oy == r
            for ox in range(-r, r + 1):
                if not ring_row and ox != -r and ox != r:
                    continue
                cx = gx + ox
                if walls[0] and (cx < 0 or cx >= nc[0]):
                    continue
                c = R.cell_number(cx % nc[0], cy, 0, nc[0], nc[1])
                for j in range(start[c], start[c + 1]):
                    if j == i:
                        continue
                    ax = pos[0, j] - xi
                    ay = pos[1, j] - yi
                    ax = R.minimum_image(ax, box[0], half_x)
                    ay = R.minimum_image(ay, box[1], half_y)
                    d2 = ax * ax + ay * ay
                    if d2 == 0.0:
                        return -1  # coincident: the triangulation's rule
                    if d2 >= 4.0 * rho2:
                        continue
                    m = cut(px, py, tag, m, qx, qy, qtag, ax, ay, j)
                    if m + 2 > px.shape[0]:
                        return -1
                    rho2 = 0.0
                    for k in range(m):
                        px[k], py[k], tag[k] = qx[k], qy[k], qtag[k]
                        rho2 = max(rho2, px[k] * px[k] + py[k] * py[k])
        if 4.0 * rho2 <= (r * step * (1.0 - 1e-12)) ** 2:  # a margin for the rounding of cell indices
            break
        r += 1
    count = 0
    for k in range(m):
        k1 = k + 1 if k + 1 < m else 0
        if tag[k] >= 0 and (px[k1] - px[k]) ** 2 + (py[k1] - py[k]) ** 2 > tol * tol:
            # in increasing order (a side per neighbour: no repeats)
            p = count
            while p > 0 and found[p - 1] > tag[k]:
                found[p] = found[p - 1]
                p -= 1
            found[p] = tag[k]
            count += 1
    return count


@cached(cells, delaunay, parallel=True)
def all_cells(pos, start, nc, box, walls, tol, out, counts):
    """Every slot's neighbours into ``out[i, :counts[i]]`` (-1 in ``counts`` where the cell
    could not be made); in fixed blocks of slots, one thread a block."""
    n = pos.shape[1]
    blocks = (n + 511) // 512
    for b in numba.prange(blocks):
        px, py, qx, qy = np.empty(MAX_SIDES + 2), np.empty(MAX_SIDES + 2), np.empty(MAX_SIDES + 2), np.empty(MAX_SIDES + 2)
        tag, qtag = np.empty(MAX_SIDES + 2, np.int64), np.empty(MAX_SIDES + 2, np.int64)
        for i in range(b * 512, min(n, (b + 1) * 512)):
            counts[i] = cell_neighbours(i, pos, start, nc, box, walls, tol, px, py, tag, qx, qy, qtag, out[i])


@cached(cells, delaunay, parallel=True)
def rows(out, counts):
    """The sorted lists ``out[i, :counts[i]]`` as compressed rows, and whether every pair
    is listed both ways (a side within rounding of ``TIE`` can be seen by one cell only)."""
    n = counts.shape[0]
    offsets = np.zeros(n + 1, dtype=np.int64)
    offsets[1:] = np.cumsum(counts)
    nbrs = np.empty(offsets[n], dtype=np.int64)
    ok = np.ones(n, dtype=np.bool_)
    for i in numba.prange(n):
        for k in range(counts[i]):
            j = out[i, k]
            nbrs[offsets[i] + k] = j
            mutual = False
            for q in range(counts[j]):
                mutual |= out[j, q] == i
            ok[i] &= mutual
    return offsets, nbrs, ok.all()


def graph(pos: np.ndarray, start: np.ndarray, nc: np.ndarray, box: np.ndarray, walls: np.ndarray):
    """The Voronoi neighbours of the slots (2D; ``start``, ``nc``: the sorted arrays' cell
    list) as :func:`flocking.backends.delaunay.graph` gives them, or ``None`` where this
    method does not apply (see the module's docstring)."""
    d, n = pos.shape
    if d != 2 or n < 2:
        return None
    spacing = (float(np.prod(box)) / n) ** 0.5
    out = np.empty((n, MAX_SIDES), dtype=np.int64)
    counts = np.empty(n, dtype=np.int64)
    all_cells(pos, start, np.asarray(nc, dtype=np.int64), box, np.asarray(walls, dtype=np.bool_),
              delaunay.TIE * spacing, out, counts)
    if counts.min() < 0:
        return None
    offsets, nbrs, mutual = rows(out, counts)
    if mutual:
        return offsets, nbrs
    return delaunay.compress(np.repeat(np.arange(n), counts), nbrs, n)  # both ways


def from_points(points: np.ndarray, box, walls, side: float = 1.0):
    """:func:`graph` for particles at ``points`` ``(n, 2)`` in the box, in their own order,
    over a cell list of cells at least ``side`` wide made here (what the tests call)."""
    points = np.asarray(points, dtype=np.float64)
    box, walls = np.asarray(box, dtype=np.float64), np.asarray(walls, dtype=np.bool_)
    nc = np.maximum(1, np.floor(box / side)).astype(np.int64)
    cell = np.empty(len(points), dtype=np.int64)
    cells.cell_indices(np.ascontiguousarray(points.T), nc, nc / box, cell)
    order = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[order], np.arange(int(np.prod(nc)) + 1)).astype(np.int64)
    found = graph(np.ascontiguousarray(points[order].T), start, nc, box, walls)
    if found is None:
        return None
    offsets, nbrs = found
    a = np.repeat(order, np.diff(offsets))
    return delaunay.compress(a, order[nbrs], len(points))
