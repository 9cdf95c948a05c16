"""The CPU step over a given neighbour list: Voronoi neighbours (``neighbours = "voronoi"``).

Each step :func:`flocking.backends.delaunay.graph` lists every slot's Voronoi neighbours
(slots, in increasing order) and the ``graph`` kernel takes the step over them: the same
functions as the ``search`` kernel of :mod:`flocking.backends.cpu_kernels`, compiled with
the same flags (:func:`~flocking.backends.cpu_kernels.variant_namespace`): each neighbour
weighed by :func:`flocking.rules.physics.neighbour` (coupling, nematic sign, vision cone,
cohesion: the displacement is the minimum image), then
:func:`~flocking.backends.cpu_kernels.advance` (delay, field, noise, chirality, move,
walls, obstacles). Work comes in fixed blocks of slots and a particle's sums follow its
list's order, so no result depends on the number of threads.
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from ..rules import rebind, source_digest
from . import cells, cpu_kernels, delaunay, intrinsics, voronoi_cells
from .features import Features

#: the text compiled into the kernel from other files, in its name in numba's cache
#: (:func:`flocking.rules.source_digest`)
SOURCES = source_digest(cells, intrinsics, cpu_kernels, delaunay, voronoi_cells)

# the flags and functions these read are bound per variant by kernel(), as in cpu_kernels
EXTENDED = COUPLING = WEIGHTED = False
DIM = 2
R = cpu_kernels.R


def voronoi_sums(i, pos, head, ids, box, tb, si, offsets, nbrs):
    """Slot ``i``'s sums over its listed neighbours (:data:`flocking.rules.step.SUMS`): the heading sum (the particle itself included unless ``WEIGHTED``), ``1 +``
    the count of those seen, and with cohesion the pull, the push and the core count."""
    d = DIM
    s = R.SUM0
    if not WEIGHTED:
        s = (head[0, i], head[1, i], head[2, i] if d == 3 else 0.0) + R.SUM0[3:]
    for q in range(offsets[i], offsets[i + 1]):
        j = nbrs[q]
        dx = R.minimum_image(pos[0, j] - pos[0, i], box[0], tb.half[0])
        dy = R.minimum_image(pos[1, j] - pos[1, i], box[1], tb.half[1])
        d2 = dx * dx + dy * dy
        dz = 0.0
        if d == 3:
            dz = R.minimum_image(pos[2, j] - pos[2, i], box[2], tb.half[2])
            d2 += dz * dz
        s = R.plus(s, pair_terms(i, j, dx, dy, dz, d2, True, pos, head, ids, tb, si))
    return R.counted(s)


def graph(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params, partial,
          threads, tb, offsets, nbrs):
    nt = max(1, min(threads, cells.work_units(nc, pos.shape[1], 1)))
    counter = np.zeros(1, dtype=np.int64)
    for t in numba.prange(nt):
        graph_blocks(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
                     partial, tb, offsets, nbrs, counter)


def graph_blocks(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, params,
                 partial, tb, offsets, nbrs, counter):
    """One thread's share of :func:`graph`: blocks of slots taken from ``counter`` until
    none is left; block ``b``'s moment sums into ``partial[b]``."""
    n = pos.shape[1]
    inv = nc / box
    nblocks = cells.work_units(nc, n, 1)
    acc = np.zeros((partial.shape[1], 1))
    while True:
        b = intrinsics.fetch_add(counter)
        if b >= nblocks:
            break
        px = 0.0
        py = 0.0
        pz = 0.0
        if EXTENDED:
            acc[:] = 0.0
        for i in range(b * cells.BLOCK, min(n, (b + 1) * cells.BLOCK)):
            si = species(ids[i], tb.bounds) if COUPLING else 0
            s = voronoi_sums(i, pos, head, ids, box, tb, si, offsets, nbrs)
            wx, wy, wz = advance(i, s, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed,
                                 params, nc, inv, box, tb)
            if EXTENDED:
                add_moments(acc, wx, wy, wz, ids[i], tb.bounds)
            else:
                px += wx
                py += wy
                pz += wz
        if EXTENDED:
            partial[b, :] = acc[:, 0]
        else:
            partial[b, 0] = px
            partial[b, 1] = py
            partial[b, 2] = pz


@functools.lru_cache(maxsize=None)
def build(features: Features, dim: int):
    """The ``graph`` kernel for ``features`` in ``dim`` dimensions (the ``search``
    kernel's variant: :func:`cpu_kernels.variant`), cached on disk under a name of its own and
    :data:`SOURCES`."""
    features = cpu_kernels.variant(features, "search")
    namespace = dict(cpu_kernels.variant_namespace(features, dim))
    namespace["voronoi_sums"] = numba.njit(inline="always")(rebind(voronoi_sums, namespace))
    namespace["graph_blocks"] = numba.njit(inline="always")(rebind(graph_blocks, namespace))
    tag = cpu_kernels.cache_tag(features, dim)
    return numba.njit(cache=True, parallel=True)(rebind(graph, namespace, f"graph_{tag}_{SOURCES}"))


def kernel(features: Features, dim: int, box, walls):
    """A step with the ``search`` kernel's arguments
    (:func:`flocking.backends.cpu_kernels.build`) over Voronoi neighbours: the lists of
    :func:`flocking.backends.voronoi_cells.graph` (2D, each particle's cell cut in
    parallel) or where that does not apply of :func:`flocking.backends.delaunay.graph`
    (Qhull), the same lists; then the ``graph`` kernel. Refuses, in one line, to be made
    without scipy."""
    delaunay.qhull()
    compiled = build(features, dim)
    box, walls = np.asarray(box, dtype=np.float64), np.asarray(walls, dtype=bool)

    def step(pos, head, spd, ids, start, nc, box_, new_pos, new_head, cell, ring, slot, t, seed, params, partial,
             threads, tb):
        found = voronoi_cells.graph(pos, start, nc, box, walls) if dim == 2 else None
        offsets, nbrs = found if found is not None else delaunay.graph(pos, box, walls)
        compiled(pos, head, spd, ids, start, nc, box_, new_pos, new_head, cell, ring, slot, t, seed, params,
                 partial, threads, tb, offsets, nbrs)

    return step
