"""Cell lists for the pair-based quantities (velocity correlation, clusters), compiled by numba.

Positions are padded to three columns (2D: ``z = 0`` and one cell along z), so one code
path serves both dimensions. Cells have side at least ``cutoff``, so every pair closer
than ``cutoff`` lies in neighbouring cells; with fewer than three cells along an axis
the neighbour list is de-duplicated, so each pair is seen exactly once per ordering,
at its minimum image, even when ``cutoff`` exceeds half the box.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True)
_pjit = numba.njit(cache=True, parallel=True)


def grid(box: np.ndarray, cutoff: float, n: int) -> np.ndarray:
    """Cells per axis (3 entries): side ``>= cutoff``, at most about ``4 n`` cells in all."""
    box = np.asarray(box, float)
    cells = np.maximum(np.floor(box / cutoff), 1).astype(np.int64)
    while np.prod(cells) > max(4 * n, 64):
        cells = np.maximum(cells // 2, 1)
    return np.concatenate([cells, np.ones(3 - len(cells), np.int64)])


@_jit
def _build(pos, box, cells):
    n = pos.shape[0]
    ncell = cells[0] * cells[1] * cells[2]
    cell_of = np.empty(n, np.int64)
    for i in range(n):
        c = 0
        for a in range(3):
            k = int(pos[i, a] / box[a] * cells[a])
            if k >= cells[a]:
                k = cells[a] - 1
            c = c * cells[a] + k
        cell_of[i] = c
    start = np.zeros(ncell + 1, np.int64)
    for i in range(n):
        start[cell_of[i] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    return start, order


@_jit
def _neighbour_cells(c, cells):
    """The distinct cells around cell ``c`` (itself included)."""
    cz = c % cells[2]
    cy = (c // cells[2]) % cells[1]
    cx = c // (cells[2] * cells[1])
    out = np.empty(27, np.int64)
    m = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                x = (cx + dx) % cells[0]
                y = (cy + dy) % cells[1]
                z = (cz + dz) % cells[2]
                d = (x * cells[1] + y) * cells[2] + z
                seen = False
                for k in range(m):
                    if out[k] == d:
                        seen = True
                if not seen:
                    out[m] = d
                    m += 1
    return out[:m]


@_jit
def _min_image(d, length):
    # |d| < length: one comparison each way instead of a floor
    if d > 0.5 * length:
        return d - length
    if d < -0.5 * length:
        return d + length
    return d


def prepare(positions: np.ndarray, box: np.ndarray, cutoff: float):
    """``(pos3, box3, cells, start, order)``: the padded arrays and the cell list."""
    n, dim = positions.shape
    pos = np.zeros((n, 3))
    pos[:, :dim] = positions
    box3 = np.ones(3)
    box3[:dim] = box
    cells = grid(box, cutoff, n)
    start, order = _build(pos, box3, cells)
    # particle data in cell order: neighbour access becomes nearly sequential
    return np.ascontiguousarray(pos[order]), box3, cells, start, order


@_pjit
def _correlation(pos, du, box, cells, start, r_max, nbins, nchunks):
    """Per chunk of cells: sums of ``du_i . du_j`` and pair counts per distance bin."""
    ncell = cells[0] * cells[1] * cells[2]
    sums = np.zeros((nchunks, nbins))
    counts = np.zeros((nchunks, nbins))
    r2max = r_max * r_max
    scale = nbins / r_max
    for chunk in numba.prange(nchunks):
        for c in range(chunk * ncell // nchunks, (chunk + 1) * ncell // nchunks):
            near = _neighbour_cells(c, cells)
            for i in range(start[c], start[c + 1]):
                for c2 in near:
                    for j in range(start[c2], start[c2 + 1]):
                        if j == i:
                            continue
                        dx = _min_image(pos[j, 0] - pos[i, 0], box[0])
                        dy = _min_image(pos[j, 1] - pos[i, 1], box[1])
                        dz = _min_image(pos[j, 2] - pos[i, 2], box[2])
                        r2 = dx * dx + dy * dy + dz * dz
                        if r2 < r2max:
                            b = int(math.sqrt(r2) * scale)
                            if b >= nbins:
                                b = nbins - 1
                            sums[chunk, b] += du[i, 0] * du[j, 0] + du[i, 1] * du[j, 1] + du[i, 2] * du[j, 2]
                            counts[chunk, b] += 1.0
    return sums.sum(axis=0), counts.sum(axis=0)


def correlation_sums(positions, du, box, r_max: float, nbins: int):
    """``(sum of du_i.du_j, number of ordered pairs i != j)`` per bin of ``[0, r_max)``."""
    pos, box3, cells, start, order = prepare(positions, box, r_max)
    du3 = np.zeros((len(du), 3))
    du3[:, : du.shape[1]] = du[order]
    nchunks = int(min(np.prod(cells), 8 * numba.get_num_threads()))
    return _correlation(pos, du3, box3, cells, start, float(r_max), int(nbins), nchunks)


@_jit
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@_jit
def _link(pos, box, cells, start, radius):
    n = pos.shape[0]
    parent = np.arange(n)
    ncell = cells[0] * cells[1] * cells[2]
    r2 = radius * radius
    for c in range(ncell):
        near = _neighbour_cells(c, cells)
        for i in range(start[c], start[c + 1]):
            for c2 in near:
                if c2 < c:
                    continue  # each pair of cells once
                j0 = i + 1 if c2 == c else start[c2]
                for j in range(j0, start[c2 + 1]):
                    dx = _min_image(pos[j, 0] - pos[i, 0], box[0])
                    dy = _min_image(pos[j, 1] - pos[i, 1], box[1])
                    dz = _min_image(pos[j, 2] - pos[i, 2], box[2])
                    if dx * dx + dy * dy + dz * dz < r2:
                        a = _find(parent, i)
                        b = _find(parent, j)
                        if a != b:
                            if a < b:
                                parent[b] = a
                            else:
                                parent[a] = b
    for i in range(n):
        parent[i] = _find(parent, i)
    return parent


def cluster_roots(positions, box, radius: float) -> np.ndarray:
    """For each particle (in input order), a representative of its cluster."""
    pos, box3, cells, start, order = prepare(positions, box, radius)
    roots_sorted = _link(pos, box3, cells, start, float(radius))
    roots = np.empty(len(order), np.int64)
    roots[order] = order[roots_sorted]
    return roots
