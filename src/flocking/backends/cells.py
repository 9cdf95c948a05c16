"""The CPU backend's cells: the grid, the parallel stable sort into cell order, and the
gathering of a unit of work's neighbour candidates.

Particles are arrays per coordinate, ``pos[a, slot]``, kept in *cell order*: every step a
parallel stable counting sort (:func:`sort_cells`: a histogram per thread over fixed
chunks, a blocked prefix sum; :func:`scatter_sorted`) rebuilds it, so the particles of one
cell, and of a *line* of cells (a row along x; in 3D one per (y, z)), are contiguous.
Stable means that within a cell particles keep last step's order, whatever the number of
threads. A unit of work (:data:`SEGMENT` columns of a line) copies, from each of the 3
(3D: 9) lines around it, its columns plus one on each side as one contiguous block
(:func:`gather_rows`: periodic images shifted as they are copied), so the candidates of a
cell are one range per neighbouring line (:func:`candidate_ranges`).

>>> from flocking import Model
>>> cell_grid(Model(n=100, box=10.0, noise=0.1)).tolist()
[9, 9]
"""

from __future__ import annotations

import numba
import numpy as np

from ..model import Model
from ..rules import cached
from ..rules import compile as compile_rules

R = compile_rules("cpu")

BLOCK = 512  # slots per block of the search kernel; fixed, so results do not depend on threads
SEGMENT = 64  # columns of cells per unit of work of the metric kernel
SCAN = 4096  # cells per block of the parallel prefix sum


def cell_grid(model: Model) -> np.ndarray:
    """Cells per axis: at least ``R`` wide (metric), at most about one per particle.

    >>> cell_grid(Model(n=100, box=10.0, noise=0.1)).tolist()
    [9, 9]
    """
    box = np.asarray(model.box, dtype=np.float64)
    if model.neighbours == "metric":
        # a hair wider than R, so rounding in the cell index can never hide a neighbour
        nc = np.floor(box / (model.radius * (1.0 + 1e-9)))
    else:
        # about 3(k+1) particles in the 3^d block around a cell
        per_cell = max(3.0 * (model.k + 1) / 3**model.dim, 0.5)
        nc = np.floor(box / (per_cell / model.density) ** (1.0 / model.dim))
    nc = np.maximum(nc, 1.0)
    cap = max(model.n, 1)
    total = np.prod(nc)
    if total > cap:
        nc = np.maximum(np.floor(nc * (cap / total) ** (1.0 / model.dim)), 1.0)
    return nc.astype(np.int64)


# -- the cell structure: parallel stable counting sort ---------------------------------


@cached(inline="always")
def cell_of(pos, i, nc, inv):
    """The cell of slot ``i``, numbered by :func:`flocking.rules.geometry.cell_number`
    (x fastest, so a row of cells is contiguous; each axis by
    :func:`flocking.rules.geometry.cell_index`: always a valid cell)."""
    c2 = R.cell_index(pos[2, i], inv[2], nc[2]) if pos.shape[0] == 3 else 0
    return R.cell_number(R.cell_index(pos[0, i], inv[0], nc[0]), R.cell_index(pos[1, i], inv[1], nc[1]), c2, nc[0],
                         nc[1])


@cached(parallel=True)
def cell_indices(pos, nc, inv, out):
    for i in numba.prange(pos.shape[1]):
        out[i] = cell_of(pos, i, nc, inv)


@cached(parallel=True)
def sort_cells(cell, hist, start):
    """Stable counting sort by cell, in parallel: ``start`` (ncells + 1) gets each cell's
    first slot and ``hist[t, c]`` the first slot of chunk ``t``'s particles in cell ``c``.

    Chunks are contiguous and their offsets are taken in chunk order, so the result is the
    unique stable order whatever the number of chunks (threads).
    """
    nt, ncells = hist.shape
    n = cell.shape[0]
    for t in numba.prange(nt):
        h = hist[t]
        h[:] = 0
        for i in range(t * n // nt, (t + 1) * n // nt):
            h[cell[i]] += 1
    nb = (ncells + SCAN - 1) // SCAN
    sums = np.zeros(nb + 1, dtype=np.int64)
    for b in numba.prange(nb):
        tot = 0
        for c in range(b * SCAN, min(ncells, (b + 1) * SCAN)):
            for t in range(nt):
                tot += hist[t, c]
        sums[b + 1] = tot
    for b in range(nb):
        sums[b + 1] += sums[b]
    for b in numba.prange(nb):
        run = sums[b]
        for c in range(b * SCAN, min(ncells, (b + 1) * SCAN)):
            start[c] = run
            for t in range(nt):
                v = hist[t, c]
                hist[t, c] = run
                run += v
    start[ncells] = n


@cached(parallel=True)
def scatter_sorted(cell, hist, pos, head, spd, ids, pos2, head2, spd2, ids2):
    """Move every particle to its slot in cell order (``hist`` from :func:`sort_cells`)."""
    nt = hist.shape[0]
    n = cell.shape[0]
    d = pos.shape[0]
    per_particle = spd.shape[0] == n
    for t in numba.prange(nt):
        h = hist[t]
        for i in range(t * n // nt, (t + 1) * n // nt):
            c = cell[i]
            s = h[c]
            h[c] = s + 1
            for a in range(d):
                pos2[a, s] = pos[a, i]
                head2[a, s] = head[a, i]
            if per_particle:
                spd2[s] = spd[i]
            ids2[s] = ids[i]


@cached(inline="always")
def neighbour_row(g, n, length):
    """Row/plane ``g`` folded into ``0..n-1`` and the shift to add to a displacement."""
    if g < 0:
        return g + n, -length
    if g >= n:
        return g - n, length
    return g, 0.0


U1 = np.uint64(1)
ALL = np.uint64(2**64 - 1)  # a `last` that masks nothing


@cached(inline="always")
def copy_range(x, y, z, hx, hy, hz, tag, lo, hi, shx, shy, shz, buf, m, d):
    """Append slots ``lo..hi`` to the buffer at ``m``, periodic shifts applied (and, unless
    ``tag`` is None, ``tag[:, slot]`` into rows ``2d, 2d + 1, ...``); returns the new end. Unsigned indices
    (here and in the reductions): numba then emits no negative-index wraparound, which
    would keep LLVM from vectorising the loops."""
    m0 = m = np.uint64(m)
    lo, hi = np.uint64(max(lo, 0)), np.uint64(max(hi, 0))
    for j in range(lo, hi):
        buf[0, m] = x[j] + shx
        buf[1, m] = y[j] + shy
        buf[d, m] = hx[j]
        buf[d + 1, m] = hy[j]
        if d == 3:
            buf[2, m] = z[j] + shz
            buf[5, m] = hz[j]
        m += U1
    if tag is not None:  # pruned when compiling for None: the plain kernel never sees it
        # a loop of its own per row: inside the loop above, a loop over the rows whose
        # length is known only at run time kept LLVM from vectorising the copy
        for a in range(tag.shape[0]):
            for j in range(lo, hi):
                buf[2 * d + a, m0 + j - lo] = tag[a, j]
    return np.int64(m)


@cached(inline="always")
def neighbour_line(gy, gz, r, nc, box, d):
    """The ``r``-th of the 3 (3D: 9) lines around line ``(gy, gz)``: its first cell and
    the shifts (y, z) to its periodic image nearest that line."""
    hz, shz = neighbour_row(gz + r // 3 - 1, nc[d - 1], box[d - 1]) if d == 3 else (0, 0.0)
    hy, shy = neighbour_row(gy + r % 3 - 1, nc[1], box[1])
    return R.cell_number(0, hy, hz, nc[0], nc[1]), shy, shz


@cached()
def gather_rows(gy, gz, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, box, buf, rows, d):
    """Copy what the cells ``c0..c1-1`` of the line of cells ``(gy, gz)`` need into
    ``buf``; returns how many entries it used, or -1 (nothing copied) if the buffer is too
    small.

    A line is a row of cells along x (in 3D, one per (y, z)). The 3 (3D: 9) lines around
    it (this one included) each hold the columns ``c0 - 1 .. c1`` as one contiguous range
    of slots, so each is copied whole (a column past an end of the line is the wrapped
    one, copied alongside with its shift), coordinates in rows ``0..d-1`` and headings in
    rows ``d..2d-1``, shifted to the periodic image nearest this line. For line ``r``,
    ``rows[r]`` = (first cell of that line, where its copy starts, where it ends, what to
    add to a slot to find its copy). Each copy is followed by three zeroed entries, so a
    reduction may read whole groups of four past its end (and multiply them by 0).
    ``box`` gives the shifts: the box itself, or along an axis with walls a shift that
    puts every wrapped copy out of reach. Unless ``tag`` is None, rows ``2d, 2d + 1, ...``
    get ``tag[:, slot]`` (the extensions' couplings to the slot's species).
    """
    nx = nc[0]
    nr = rows.shape[0]
    need = 0
    for r in range(nr):
        row0, _, _ = neighbour_line(gy, gz, r, nc, box, d)
        need += start[row0 + min(c1 + 1, nx)] - start[row0 + max(c0 - 1, 0)] + 3
        if c0 == 0:
            need += start[row0 + nx] - start[row0 + nx - 1]
        if c1 == nx:
            need += start[row0 + 1] - start[row0]
    if need > buf.shape[1]:
        return -1
    m = 0
    for r in range(nr):
        row0, shy, shz = neighbour_line(gy, gz, r, nc, box, d)
        rows[r, 0] = row0
        rows[r, 1] = m
        if c0 == 0:
            m = copy_range(x, y, z, hx, hy, hz, tag, start[row0 + nx - 1], start[row0 + nx], -box[0], shy, shz, buf,
                           m, d)
        first = start[row0 + max(c0 - 1, 0)]
        rows[r, 3] = m - first
        m = copy_range(x, y, z, hx, hy, hz, tag, first, start[row0 + min(c1 + 1, nx)], 0.0, shy, shz, buf, m, d)
        if c1 == nx:
            m = copy_range(x, y, z, hx, hy, hz, tag, start[row0], start[row0 + 1], box[0], shy, shz, buf, m, d)
        rows[r, 2] = m
        for a in range(buf.shape[0]):
            buf[a, m], buf[a, m + 1], buf[a, m + 2] = 0.0, 0.0, 0.0
        m += 3
    return m


@cached(inline="always")
def gather_unit(u, nseg, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, out, d):
    """Unit ``u`` of the line kernels, segment ``u % nseg`` of line ``u // nseg`` (as
    :func:`work_units` counts them): its line ``(gy, gz)``, columns ``c0..c1-1`` and slots
    ``s0..s1-1``, with its candidates gathered into ``buf`` (:func:`gather_rows`; ``shifts``
    and ``tag`` as there). Returns those and ``buf`` and ``out`` (sums, a column per slot),
    each replaced by a larger one where the unit needs more room."""
    line = u // nseg
    gy, gz = line % nc[1], line // nc[1]
    c0 = (u % nseg) * SEGMENT
    c1 = min(nc[0], c0 + SEGMENT)
    while gather_rows(gy, gz, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, d) < 0:
        buf = np.empty((buf.shape[0], 2 * buf.shape[1]))
    s0, s1 = start[R.cell_number(c0, gy, gz, nc[0], nc[1])], start[R.cell_number(c1, gy, gz, nc[0], nc[1])]
    if s1 - s0 > out.shape[1]:
        out = np.empty((out.shape[0], 2 * (s1 - s0)))
    return gy, gz, c0, c1, s0, s1, buf, out


@cached(inline="always")
def candidate_ranges(cx, nx, start, rows, ranges):
    """Where, in the buffer of :func:`gather_rows`, the candidates of column ``cx`` lie:
    one range per neighbouring line, into ``ranges``."""
    for r in range(rows.shape[0]):
        row0, delta = rows[r, 0], rows[r, 3]
        ranges[r, 0] = rows[r, 1] if cx == 0 else start[row0 + cx - 1] + delta
        ranges[r, 1] = rows[r, 2] if cx == nx - 1 else start[row0 + cx + 2] + delta


@cached(inline="always")
def axis_cells(c, n):
    """First neighbour offset and number of distinct neighbour cells along an axis."""
    if n >= 3:
        return c - 1, 3
    return 0, n  # absolute cells 0..n-1, each once


@cached()
def work_units(nc, n, mode):
    """How many units of work a step is split into: segments of lines of cells for the
    fast metric kernel (mode 0), blocks of slots otherwise. Fixed by the model alone."""
    if mode == 0:
        return (np.prod(nc) // nc[0]) * ((nc[0] + SEGMENT - 1) // SEGMENT)
    return (n + BLOCK - 1) // BLOCK
