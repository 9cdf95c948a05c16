"""The default backend: numba kernels over cell lists, multi-threaded and deterministic.

Layout. The particle arrays are *structure of arrays*, ``pos[a, slot]`` and
``head[a, slot]``, kept in *cell order*: after every step a stable, parallel counting
sort by cell scatters them into the other half of a double buffer, so the particles of
one cell, and of a row of cells, are contiguous. ``ids[slot]`` (int32) is the particle
behind a slot; it keys the random numbers and the delay ring and gives the user the id
order back. Constant speeds are stored as one number, not an array.

Cells. Metric neighbours use cells at least ``R`` wide (at most about one per particle)
numbered row by row with x fastest, so a *line* of cells (a row; in 3D one per (y, z)) is
one contiguous range of slots. Work comes in units of ``_SEGMENT`` columns of a line: a
unit copies the slots its cells need from the 3 (3D: 9) lines around it, one contiguous
block per line shifted to the nearest periodic image (:func:`_gather_rows`), so the
candidates of a cell are one range per neighbouring line and the pair loop has no branch
and vectorises. It sums every cell of the unit, then updates every particle of it in one
loop. An axis with fewer than three cells (a box smaller than ``3R``) goes through a
generic kernel that takes the minimum image per pair, so no particle is counted twice.
Topological neighbours search rings of cells outward until the k-th distance is inside the
searched region.

Determinism. Work is split into fixed units (segments of lines of cells; blocks of slots
for the search kernel) that threads take from an atomic counter as they become free (which
balances clustered states and busy machines). A particle's new heading depends only on the
sorted arrays and on counter-based random numbers, and the sort is stable: within a cell,
particles keep the order they had the step before (id order when a run starts), whatever
the number of threads. A checkpoint saves that order (:meth:`CPUBackend.memory`), so a run
continued from it adds neighbours in the same order as one that never stopped. The polar
order is summed per unit, then over units in order. No result depends on the number of
threads.

Delay. The sum of the neighbours' headings (without the particle itself) and ``1 +`` their
count at step ``t`` is exactly what step ``t + tau`` needs: ``_ring[t % tau, id]`` holds
it, indexed by particle id, and replaces a second neighbour search.

>>> from flocking import Model, State
>>> from flocking.backends.cpu import CPUBackend
>>> model = Model(n=200, box=10.0, noise=0.5, seed=2)
>>> backend = CPUBackend(model, State.random(model))
>>> phi = backend.advance(5)
>>> backend.state.step, phi.shape
(5, (5,))
"""

from __future__ import annotations

import math
import os

# Idle OpenMP threads spin only briefly (about a microsecond), then sleep: long enough to
# bridge the back-to-back parallel loops of a step (waking a sleeping thread costs tens of
# microseconds, which halved throughput at N = 1e4), short enough not to take a busy
# machine's cores from other work (long spins halved throughput there; see
# docs/performance.md). Set either variable to override.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba.core import cgutils, types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from ..model import Model, ParameterError  # noqa: E402
from ..observables import moment_width  # noqa: E402
from ..state import State  # noqa: E402
from .kernels import minimum_image, update_2d, update_3d, wrap  # noqa: E402

_BLOCK = 512  # slots per block of the search kernel; fixed, so results do not depend on threads
_SEGMENT = 64  # columns of cells per unit of work of the metric kernel
_SCAN = 4096  # cells per block of the parallel prefix sum


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


@intrinsic
def _fetch_add(typingctx, counter):
    """Atomically ``counter[0] += 1``, returning the old value: hands out work blocks."""
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen


@intrinsic
def _prefetch(typingctx, ring, slot, pid):
    """Hint the cache to fetch ``ring[slot, pid]`` for writing (``llvm.prefetch``)."""
    sig = types.void(ring, slot, pid)

    def codegen(context, builder, signature, args):
        from llvmlite import ir

        ary = context.make_array(signature.args[0])(context, builder, args[0])
        idx = [context.cast(builder, args[1], signature.args[1], types.intp),
               context.cast(builder, args[2], signature.args[2], types.intp), context.get_constant(types.intp, 0)]
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, idx)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0i8")
        builder.call(fn, [builder.bitcast(ptr, i8p), i32(1), i32(3), i32(1)])
        return context.get_dummy_value()

    return sig, codegen


# -- the cell structure: parallel stable counting sort ---------------------------------


@numba.njit(cache=True, inline="always")
def _cell_of(pos, i, nc, inv):
    """Row-major cell index with x fastest, so a row of cells is contiguous.

    Always a valid cell, whatever the coordinate: below 0 or NaN gives the first cell of
    the axis, beyond the box the last (a state read from a foreign file may hold anything;
    the step then stays in bounds and the non-finite polar order tells the caller)."""
    c = 0
    for a in range(pos.shape[0] - 1, -1, -1):
        x = pos[a, i] * inv[a]
        ca = 0
        if x >= 1.0:  # False for NaN
            ca = nc[a] - 1 if x >= nc[a] else int(x)
        c = c * nc[a] + ca
    return c


@numba.njit(cache=True, parallel=True)
def _cells(pos, nc, inv, out):
    for i in numba.prange(pos.shape[1]):
        out[i] = _cell_of(pos, i, nc, inv)


@numba.njit(cache=True, parallel=True)
def _sort(cell, hist, start):
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
    nb = (ncells + _SCAN - 1) // _SCAN
    sums = np.zeros(nb + 1, dtype=np.int64)
    for b in numba.prange(nb):
        tot = 0
        for c in range(b * _SCAN, min(ncells, (b + 1) * _SCAN)):
            for t in range(nt):
                tot += hist[t, c]
        sums[b + 1] = tot
    for b in range(nb):
        sums[b + 1] += sums[b]
    for b in numba.prange(nb):
        run = sums[b]
        for c in range(b * _SCAN, min(ncells, (b + 1) * _SCAN)):
            start[c] = run
            for t in range(nt):
                v = hist[t, c]
                hist[t, c] = run
                run += v
    start[ncells] = n


@numba.njit(cache=True, parallel=True)
def _scatter(cell, hist, pos, head, spd, ids, pos2, head2, spd2, ids2):
    """Move every particle to its slot in cell order (``hist`` from :func:`_sort`)."""
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


# -- neighbour sums -------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _neighbour_row(g, n, length):
    """Row/plane ``g`` folded into ``0..n-1`` and the shift to add to a displacement."""
    if g < 0:
        return g + n, -length
    if g >= n:
        return g - n, length
    return g, 0.0


_U1 = np.uint64(1)
_ALL = np.uint64(2**64 - 1)  # a `last` that masks nothing


@numba.njit(cache=True, inline="always")
def _copy(x, y, z, hx, hy, hz, tag, lo, hi, shx, shy, shz, buf, m, d):
    """Append slots ``lo..hi`` to the buffer at ``m``, periodic shifts applied (and, unless
    ``tag`` is None, ``tag[:, slot]`` into rows ``2d, 2d + 1, ...``); returns the new end. Unsigned indices
    (here and in the reductions): numba then emits no negative-index wraparound, which
    would keep LLVM from vectorising the loops."""
    m = np.uint64(m)
    for j in range(np.uint64(max(lo, 0)), np.uint64(max(hi, 0))):
        buf[0, m] = x[j] + shx
        buf[1, m] = y[j] + shy
        buf[d, m] = hx[j]
        buf[d + 1, m] = hy[j]
        if d == 3:
            buf[2, m] = z[j] + shz
            buf[5, m] = hz[j]
        if tag is not None:  # pruned when compiling for None: the plain kernel never sees it
            for a in range(tag.shape[0]):
                buf[2 * d + a, m] = tag[a, j]
        m += _U1
    return np.int64(m)


@numba.njit(cache=True, inline="always")
def _neighbour_line(gy, gz, r, nc, box, d):
    """The ``r``-th of the 3 (3D: 9) lines around line ``(gy, gz)``: its first cell and
    the shifts (y, z) to its periodic image nearest that line."""
    hz, shz = _neighbour_row(gz + r // 3 - 1, nc[d - 1], box[d - 1]) if d == 3 else (0, 0.0)
    hy, shy = _neighbour_row(gy + r % 3 - 1, nc[1], box[1])
    return (hz * nc[1] + hy) * nc[0], shy, shz


@numba.njit(cache=True)
def _gather_rows(line, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, box, buf, rows, d):
    """Copy what the cells ``c0..c1-1`` of a line of cells need into ``buf``; returns how
    many entries it used, or -1 (nothing copied) if the buffer is too small.

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
    nx, ny = nc[0], nc[1]
    gy, gz = line % ny, line // ny
    nr = rows.shape[0]
    need = 0
    for r in range(nr):
        row0, _, _ = _neighbour_line(gy, gz, r, nc, box, d)
        need += start[row0 + min(c1 + 1, nx)] - start[row0 + max(c0 - 1, 0)] + 3
        if c0 == 0:
            need += start[row0 + nx] - start[row0 + nx - 1]
        if c1 == nx:
            need += start[row0 + 1] - start[row0]
    if need > buf.shape[1]:
        return -1
    m = 0
    for r in range(nr):
        row0, shy, shz = _neighbour_line(gy, gz, r, nc, box, d)
        rows[r, 0] = row0
        rows[r, 1] = m
        if c0 == 0:
            m = _copy(x, y, z, hx, hy, hz, tag, start[row0 + nx - 1], start[row0 + nx], -box[0], shy, shz, buf, m, d)
        first = start[row0 + max(c0 - 1, 0)]
        rows[r, 3] = m - first
        m = _copy(x, y, z, hx, hy, hz, tag, first, start[row0 + min(c1 + 1, nx)], 0.0, shy, shz, buf, m, d)
        if c1 == nx:
            m = _copy(x, y, z, hx, hy, hz, tag, start[row0], start[row0 + 1], box[0], shy, shz, buf, m, d)
        rows[r, 2] = m
        for a in range(buf.shape[0]):
            buf[a, m], buf[a, m + 1], buf[a, m + 2] = 0.0, 0.0, 0.0
        m += 3
    return m


@numba.njit(cache=True, inline="always")
def _gather_unit(u, nseg, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, out, d):
    """Unit ``u`` of the line kernels, segment ``u % nseg`` of line ``u // nseg`` (as
    :func:`_work_units` counts them): its line, columns ``c0..c1-1`` and slots ``s0..s1-1``,
    with its candidates gathered into ``buf`` (:func:`_gather_rows`; ``shifts`` and ``tag``
    as there). Returns those and ``buf`` and ``out`` (sums, a column per slot), each
    replaced by a larger one where the unit needs more room."""
    line = u // nseg
    c0 = (u % nseg) * _SEGMENT
    c1 = min(nc[0], c0 + _SEGMENT)
    while _gather_rows(line, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, d) < 0:
        buf = np.empty((buf.shape[0], 2 * buf.shape[1]))
    s0, s1 = start[line * nc[0] + c0], start[line * nc[0] + c1]
    if s1 - s0 > out.shape[1]:
        out = np.empty((out.shape[0], 2 * (s1 - s0)))
    return line, c0, c1, s0, s1, buf, out


@numba.njit(cache=True, inline="always")
def _ranges(cx, nx, start, rows, ranges):
    """Where, in the buffer of :func:`_gather_rows`, the candidates of column ``cx`` lie:
    one range per neighbouring line, into ``ranges``."""
    for r in range(rows.shape[0]):
        row0, delta = rows[r, 0], rows[r, 3]
        ranges[r, 0] = rows[r, 1] if cx == 0 else start[row0 + cx - 1] + delta
        ranges[r, 1] = rows[r, 2] if cx == nx - 1 else start[row0 + cx + 2] + delta


@numba.njit(cache=True, inline="always")
def _term_2d(buf, j, last, xi, yi, r2):
    """Candidate ``j``'s heading and 1 if ``j <= last`` and it is within ``R`` of
    ``(xi, yi)``, else zeros (multiplied by 0 or 1, not branched on: data-dependent
    branches mispredict and keep the lanes from being vectorised)."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    w = 1.0 if (dx * dx + dy * dy < r2) & (j <= last) else 0.0
    return buf[2, j] * w, buf[3, j] * w, w


@numba.njit(cache=True, inline="always")
def _term_3d(buf, j, last, xi, yi, zi, r2):
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    dz = buf[2, j] - zi
    w = 1.0 if (dx * dx + dy * dy + dz * dz < r2) & (j <= last) else 0.0
    return buf[3, j] * w, buf[4, j] * w, buf[5, j] * w, w


# The reductions sum in four interleaved lanes (within a range, candidate lo + 4g + l goes
# to lane l; a last, partial group of four is masked), range after range, then the lanes
# in a fixed order: independent chains that LLVM's SLP vectoriser packs into SIMD registers
# without reordering any addition, so the result is fixed by this source. (Letting the
# optimiser reassociate, fastmath-style, vectorised too, but code compiled in one process
# and code loaded from numba's cache then rounded differently: a first run and a second
# run of the same seed differed in the last bits.)


@numba.njit(cache=True)
def _reduce_2d(buf, ranges, x, y, i0, i1, r2, out, o):
    """For slots ``i0..i1``: sum of headings and count of the candidates in the buffer
    ``ranges`` within ``R`` (self included) into ``out[:, o + i - i0]``."""
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
                last = _ALL if j < m4 else hi - _U1
                p0, q0, w0 = _term_2d(buf, j, last, xi, yi, r2)
                p1, q1, w1 = _term_2d(buf, j + _U1, last, xi, yi, r2)
                p2, q2, w2 = _term_2d(buf, j + np.uint64(2), last, xi, yi, r2)
                p3, q3, w3 = _term_2d(buf, j + np.uint64(3), last, xi, yi, r2)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (n0 + n1) + (n2 + n3)


@numba.njit(cache=True)
def _reduce_3d(buf, ranges, x, y, z, i0, i1, r2, out, o):
    """As :func:`_reduce_2d`, in 3D."""
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
                last = _ALL if j < m4 else hi - _U1
                p0, q0, r0, w0 = _term_3d(buf, j, last, xi, yi, zi, r2)
                p1, q1, r1, w1 = _term_3d(buf, j + _U1, last, xi, yi, zi, r2)
                p2, q2, r2_, w2 = _term_3d(buf, j + np.uint64(2), last, xi, yi, zi, r2)
                p3, q3, r3, w3 = _term_3d(buf, j + np.uint64(3), last, xi, yi, zi, r2)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                c0, c1, c2, c3 = c0 + r0, c1 + r1, c2 + r2_, c3 + r3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (c0 + c1) + (c2 + c3)
        out[3, o + i - i0] = (n0 + n1) + (n2 + n3)


@numba.njit(cache=True, inline="always")
def _axis_cells(c, n):
    """First neighbour offset and number of distinct neighbour cells along an axis."""
    if n >= 3:
        return c - 1, 3
    return 0, n  # absolute cells 0..n-1, each once


@numba.njit(cache=True)
def _generic_sums(i, c, pos, head, start, nc, box, half, r2):
    """Like the fast path, for grids with fewer than three cells along some axis: each
    cell of such an axis is visited once and every pair takes the minimum image."""
    d = pos.shape[0]
    o0, n0 = _axis_cells(c % nc[0], nc[0])
    o1, n1 = _axis_cells((c // nc[0]) % nc[1], nc[1])
    o2, n2 = 0, 1
    if d == 3:
        o2, n2 = _axis_cells(c // (nc[0] * nc[1]), nc[2])
    sx = 0.0
    sy = 0.0
    sz = 0.0
    count = 0
    for k2 in range(n2):
        g2 = (o2 + k2) % nc[2] if d == 3 else 0
        for k1 in range(n1):
            g1 = (o1 + k1) % nc[1]
            for k0 in range(n0):
                g0 = (o0 + k0) % nc[0]
                cell = (g2 * nc[1] + g1) * nc[0] + g0
                for j in range(start[cell], start[cell + 1]):
                    d2 = 0.0
                    for a in range(d):
                        dx = minimum_image(pos[a, j] - pos[a, i], box[a], half[a])
                        d2 += dx * dx
                    if d2 < r2:
                        sx += head[0, j]
                        sy += head[1, j]
                        if d == 3:
                            sz += head[2, j]
                        count += 1
    return sx, sy, sz, count


@numba.njit(cache=True)
def _topological(i, c, pos, head, ids, start, nc, box, half, k, best_d2, best_id, best_slot, cone, cos_v):
    """The k nearest others of slot ``i`` into ``best_slot``; returns how many were found.

    Rings of cells (Chebyshev distance r in cell offsets) are searched outward until the
    k-th distance is below the distance to any unsearched cell. Ties go to the lower id.
    With ``cone``, only others within the vision cone count (``u_i . r >= |r| cos_v``).
    An axis with walls has ``half = inf``: no minimum image along it.
    """
    d = pos.shape[0]
    c0 = c % nc[0]
    c1 = (c // nc[0]) % nc[1]
    c2 = c // (nc[0] * nc[1]) if d == 3 else 0
    lo0, lo1 = (nc[0] - 1) // 2, (nc[1] - 1) // 2
    hi0, hi1 = nc[0] - 1 - lo0, nc[1] - 1 - lo1
    lo2, hi2 = 0, 0
    if d == 3:
        lo2 = (nc[2] - 1) // 2
        hi2 = nc[2] - 1 - lo2
    # distance from the particle to the faces of its own cell, the closest first
    margin = np.inf
    for a in range(d):
        w = box[a] / nc[a]
        ca = c0 if a == 0 else (c1 if a == 1 else c2)
        f = pos[a, i] - ca * w
        margin = min(margin, f, w - f)
    width = np.inf
    for a in range(d):
        width = min(width, box[a] / nc[a])
    margin = max(margin, 0.0)
    rmax = max(lo0, hi0, lo1, hi1, lo2, hi2)
    found = 0
    r = 0
    while True:
        for o2 in range(-min(r, lo2), min(r, hi2) + 1):
            g2 = (c2 + o2) % nc[2] if d == 3 else 0
            for o1 in range(-min(r, lo1), min(r, hi1) + 1):
                g1 = (c1 + o1) % nc[1]
                edge = abs(o1) == r or abs(o2) == r
                for o0 in range(-min(r, lo0), min(r, hi0) + 1):
                    if edge or abs(o0) == r:
                        g0 = (c0 + o0) % nc[0]
                        cell = (g2 * nc[1] + g1) * nc[0] + g0
                        for j in range(start[cell], start[cell + 1]):
                            if j == i:
                                continue
                            d2 = 0.0
                            dot = 0.0
                            for a in range(d):
                                dx = minimum_image(pos[a, j] - pos[a, i], box[a], half[a])
                                d2 += dx * dx
                                dot += head[a, i] * dx
                            if cone and not dot >= math.sqrt(d2) * cos_v:
                                continue
                            jid = ids[j]
                            if found == k and (d2 > best_d2[k - 1] or (d2 == best_d2[k - 1] and jid > best_id[k - 1])):
                                continue
                            p = found if found < k else k - 1
                            while p > 0 and (best_d2[p - 1] > d2 or (best_d2[p - 1] == d2 and best_id[p - 1] > jid)):
                                best_d2[p] = best_d2[p - 1]
                                best_id[p] = best_id[p - 1]
                                best_slot[p] = best_slot[p - 1]
                                p -= 1
                            best_d2[p] = d2
                            best_id[p] = jid
                            best_slot[p] = j
                            if found < k:
                                found += 1
        if r >= rmax:
            break
        if found == k and best_d2[k - 1] < (r * width + margin) ** 2:
            break
        r += 1
    return found


# -- one step -------------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _swap_delay(ring, slot, pid, ox, oy, oz, total, d):
    """The delay ring's slot holds the sums of ``delay`` steps ago: return them
    (others' heading sum and ``1 +`` their count) and store today's in their place."""
    osx, osy, osz, ototal = ring[slot, pid, 0], ring[slot, pid, 1], 0.0, ring[slot, pid, d]
    ring[slot, pid, 0] = ox
    ring[slot, pid, 1] = oy
    if d == 3:
        osz = ring[slot, pid, 2]
        ring[slot, pid, 2] = oz
    ring[slot, pid, d] = total
    return osx, osy, osz, ototal


@numba.njit(cache=True, inline="always")
def _advance_particle(i, sx, sy, sz, total, pos, head, spd, ids, new_pos, new_head, cell, ring, slot,
                      step, seed, eta, vectorial, epsilon, delay, dt, backward, nc, inv, box):
    """Slot ``i``'s new heading and position into ``new_*`` and its new cell into ``cell``,
    from the sum ``S`` of its neighbours' headings and their number ``total``, both with
    the particle itself. Returns the new heading (``wz`` is 0 in 2D)."""
    d, n = pos.shape
    if delay > 0:
        # ring rows are read by particle id, in no particular order: ask for the row a few
        # particles ahead so that its cache miss overlaps work
        _prefetch(ring, slot, ids[min(np.int64(i) + 4, n - 1)])
        oz = sz - head[2, i] if d == 3 else 0.0
        osx, osy, osz, total = _swap_delay(ring, slot, ids[i], sx - head[0, i], sy - head[1, i], oz, total, d)
        sx = head[0, i] + osx
        sy = head[1, i] + osy
        if d == 3:
            sz = head[2, i] + osz
    ds = (spd[i] if spd.shape[0] == n else spd[0]) * dt
    if d == 2:
        ux, uy = head[0, i], head[1, i]
        wx, wy = update_2d(ux, uy, sx, sy, total, epsilon, eta, vectorial, seed, step, ids[i], 0.0, 0.0, 0.0, 0.0)
        wz = 0.0
        new_head[0, i], new_head[1, i] = wx, wy
        if backward:
            new_pos[0, i] = wrap(pos[0, i] + ds * wx, box[0])
            new_pos[1, i] = wrap(pos[1, i] + ds * wy, box[1])
        else:
            new_pos[0, i] = wrap(pos[0, i] + ds * ux, box[0])
            new_pos[1, i] = wrap(pos[1, i] + ds * uy, box[1])
    else:
        ux, uy, uz = head[0, i], head[1, i], head[2, i]
        wx, wy, wz = update_3d(ux, uy, uz, sx, sy, sz, total, epsilon, eta, vectorial, seed, step, ids[i],
                               0.0, 0.0, 0.0, 0.0)
        new_head[0, i], new_head[1, i], new_head[2, i] = wx, wy, wz
        if backward:
            ux, uy, uz = wx, wy, wz
        new_pos[0, i] = wrap(pos[0, i] + ds * ux, box[0])
        new_pos[1, i] = wrap(pos[1, i] + ds * uy, box[1])
        new_pos[2, i] = wrap(pos[2, i] + ds * uz, box[2])
    cell[i] = _cell_of(new_pos, i, nc, inv)
    return wx, wy, wz


@numba.njit(cache=True)
def _work_units(nc, n, mode):
    """How many units of work a step is split into: segments of lines of cells for the
    fast metric kernel (mode 0), blocks of slots otherwise. Fixed by the model alone."""
    if mode == 0:
        return (np.prod(nc) // nc[0]) * ((nc[0] + _SEGMENT - 1) // _SEGMENT)
    return (n + _BLOCK - 1) // _BLOCK


@numba.njit(cache=True, parallel=True)
def _step_lines(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, p, partial,
                threads):
    """One step of the metric model on a grid of at least three cells per axis, from the
    sorted arrays into ``new_*`` (same slots); ``cell`` gets each new cell and
    ``partial[u]`` the sum of unit ``u``'s new headings. ``threads`` only splits the work.

    ``p`` packs the scalar parameters: r2, k (0 for metric), eta, vectorial, epsilon,
    delay, dt, backward, (unused), mode (0 here, 1 generic metric, 2 topological).
    """
    d, n = pos.shape
    r2, eta, vectorial, epsilon = p[0], p[2], p[3] != 0.0, p[4]
    delay, dt, backward = int(p[5]), p[6], p[7] != 0.0
    inv = nc / box
    nx = nc[0]
    nseg = (nx + _SEGMENT - 1) // _SEGMENT
    nunits = _work_units(nc, n, 0)
    nt = max(1, min(threads, nunits))
    counter = np.zeros(1, dtype=np.int64)
    for t in numba.prange(nt):
        # views taken once per thread: a view in the hot loop costs an atomic refcount
        x, y, z = pos[0], pos[1], pos[d - 1]
        hx, hy, hz = head[0], head[1], head[d - 1]
        buf = np.empty((2 * d, 4096))
        rows = np.empty((3 if d == 2 else 9, 4), dtype=np.int64)
        ranges = np.empty((3 if d == 2 else 9, 2), dtype=np.int64)
        out = np.empty((d + 1, 16))
        while True:
            # units go to whichever thread is free: balanced when particles cluster or
            # when another program holds a core; a unit's result never depends on who
            u = _fetch_add(counter)
            if u >= nunits:
                break
            line, c0, c1, s0, s1, buf, out = _gather_unit(u, nseg, x, y, z, hx, hy, hz, None, start, nc, box, buf,
                                                          rows, out, d)
            # first the sums of every particle of the segment, then the updates in one
            # loop: its iterations are independent, so the processor overlaps their long
            # chains of dependent operations (it cannot across the reductions)
            for cx in range(c0, c1):
                c = line * nx + cx
                _ranges(cx, nx, start, rows, ranges)
                if d == 2:
                    _reduce_2d(buf, ranges, x, y, start[c], start[c + 1], r2, out, start[c] - s0)
                else:
                    _reduce_3d(buf, ranges, x, y, z, start[c], start[c + 1], r2, out, start[c] - s0)
            px = 0.0
            py = 0.0
            pz = 0.0
            # unsigned slots: no negative-index wraparound on every access
            for i in range(np.uint64(max(s0, 0)), np.uint64(max(s1, 0))):
                q = np.int64(i) - s0
                sz = out[2, q] if d == 3 else 0.0
                wx, wy, wz = _advance_particle(i, out[0, q], out[1, q], sz, out[d, q],
                                               pos, head, spd, ids, new_pos, new_head, cell, ring, slot,
                                               step, seed, eta, vectorial, epsilon, delay, dt, backward,
                                               nc, inv, box)
                px += wx
                py += wy
                pz += wz
            partial[u, 0] = px
            partial[u, 1] = py
            partial[u, 2] = pz


@numba.njit(cache=True, parallel=True)
def _step_search(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, p, partial,
                 threads):
    """As :func:`_step_lines`, for topological neighbours (mode 2) and for metric grids
    with fewer than three cells along some axis (mode 1), over blocks of slots."""
    d, n = pos.shape
    r2, k, eta, vectorial, epsilon = p[0], int(p[1]), p[2], p[3] != 0.0, p[4]
    delay, dt, backward, mode = int(p[5]), p[6], p[7] != 0.0, int(p[9])
    half = box / 2.0
    inv = nc / box
    ncells = start.shape[0] - 1
    nblocks = _work_units(nc, n, 1)
    nt = max(1, min(threads, nblocks))
    counter = np.zeros(1, dtype=np.int64)
    for t in numba.prange(nt):
        best_d2 = np.empty(max(k, 1))
        best_id = np.empty(max(k, 1), dtype=np.int64)
        best_slot = np.empty(max(k, 1), dtype=np.int64)
        while True:
            b = _fetch_add(counter)
            if b >= nblocks:
                break
            s0 = b * _BLOCK
            s1 = min(n, s0 + _BLOCK)
            c = np.searchsorted(start, s0, side="right") - 1
            px = 0.0
            py = 0.0
            pz = 0.0
            while c < ncells and start[c] < s1:
                for i in range(max(start[c], s0), min(start[c + 1], s1)):
                    sz = 0.0
                    if mode == 1:
                        sx, sy, sz, count = _generic_sums(i, c, pos, head, start, nc, box, half, r2)
                    else:
                        found = _topological(i, c, pos, head, ids, start, nc, box, half, k, best_d2, best_id,
                                             best_slot, False, 0.0)
                        sx = head[0, i]
                        sy = head[1, i]
                        if d == 3:
                            sz = head[2, i]
                        for q in range(found):
                            j = best_slot[q]
                            sx += head[0, j]
                            sy += head[1, j]
                            if d == 3:
                                sz += head[2, j]
                        count = found + 1
                    wx, wy, wz = _advance_particle(i, sx, sy, sz, float(count), pos, head, spd, ids, new_pos,
                                                   new_head, cell, ring, slot, step, seed, eta, vectorial,
                                                   epsilon, delay, dt, backward, nc, inv, box)
                    px += wx
                    py += wy
                    pz += wz
                c += 1
            partial[b, 0] = px
            partial[b, 1] = py
            partial[b, 2] = pz


@numba.njit(cache=True, parallel=True)
def _frame(pos, head, spd, ids, box, points, velocities):
    """``points[id] = pos - L/2`` and ``velocities[id] = speed * head`` (float32, z = 0 in 2D),
    rounded from the same doubles as NumPy would."""
    d, n = pos.shape
    per_particle = spd.shape[0] == n and n > 1
    for s in numba.prange(n):
        i = ids[s]
        v = spd[s] if per_particle else spd[0]
        for a in range(3):
            if a < d:
                points[i, a] = np.float32(pos[a, s] - box[a] / 2.0)
                velocities[i, a] = np.float32(v * head[a, s])
            else:
                points[i, a] = np.float32(0.0)
                velocities[i, a] = np.float32(0.0)


class CPUBackend:
    """Cell lists and numba threads; bitwise reproducible for any ``NUMBA_NUM_THREADS``."""

    name = "cpu"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Peak memory of a run: the sorted arrays (double-buffered; a written frame lives
        in the spare half), ids, cells, speeds, the delay ring and the sums that prime it,
        the histograms, and the id-ordered ``state`` copy a checkpoint takes (measured:
        82 bytes a particle in 2D; a run writing a trajectory adds the writer's copy of a
        frame, 24, for 107 in all)."""
        d = model.dim
        delay = 8 * (model.delay + 1) * (d + 1) + 4 if model.delay else 0
        speeds = 24 if model.speeds == "uniform" else 0
        per_particle = 32 * d + 12 + speeds + delay + 16 * d + 8
        return model.n * per_particle + 4 * (numba.get_num_threads() + 1) * int(np.prod(cell_grid(model)))

    def __init__(self, model: Model, state: State, memory: dict | None = None):
        self.model = model
        n, d = state.n, state.dim
        itype = np.int32 if n < 2**31 - 1 else np.int64
        self._box = np.asarray(model.box, dtype=np.float64)
        self._nc = cell_grid(model)
        self._ncells = int(np.prod(self._nc))
        ctype = np.int32 if self._ncells < 2**31 - 1 else np.int64
        self._start = np.zeros(self._ncells + 1, dtype=itype)
        self._hist = np.zeros((numba.get_num_threads(), self._ncells), dtype=itype)
        self._cell = np.empty(n, dtype=ctype)
        self._pos, self._head = np.empty((d, n)), np.empty((d, n))
        # the other half of the double buffer, allocated when first needed: a state made
        # only to start a simulation is gone by then
        self._spare = None
        self._ids, self._tmp_ids = np.empty(n, dtype=itype), np.empty(n, dtype=itype)
        speeds = state.speeds
        if n and (speeds.strides == (0,) or np.all(speeds == speeds[0])):
            self._spd, self._tmp_spd = speeds[:1].copy(), speeds[:1].copy()  # one number
        else:
            self._spd, self._tmp_spd = np.empty(n), np.empty(n)
        self._step_count = state.step
        self._extensions = ()  # the extra arguments of the kernel for a model with extensions
        if model.neighbours == "topological":
            mode = 2
        else:
            mode = 0 if np.all(self._nc >= 3) else 1
        self._kernel = _step_lines if mode == 0 else _step_search
        units = min(mode, 1)
        if model.extended:
            from . import cpu_extensions

            self._kernel, units = cpu_extensions.kernel(mode)
            self._extensions = cpu_extensions.parameters(model)
        self._partial = np.zeros((_work_units(self._nc, n, units), moment_width(model) if model.extended else 3))
        self._params = np.array([
            model.radius**2, model.k if model.neighbours == "topological" else 0, model.noise,
            model.noise_type == "vectorial", model.alignment, model.delay, model.dt,
            model.update == "backward", 0.0, mode,
        ], dtype=np.float64)
        self._seed = np.uint64(model.seed)  # its own argument: a double would round seeds above 2**53
        # ring[t % delay, id]: the neighbours' heading sum and 1 + their count at step t
        self._ring = np.zeros((max(model.delay, 1), n if model.delay else 1, d + 1))
        self._load(state, memory)

    def memory(self) -> dict[str, np.ndarray]:
        """What the backend remembers beyond the state: the order of the particles (ids
        slot by slot: within a cell it is the order of earlier steps, which the sums
        follow) and the delay ring, indexed by id."""
        memory = {"order": self._ids.copy()}
        if self.model.delay:
            memory["ring"] = self._ring.copy()
        return memory

    def _load(self, state: State, memory: dict | None) -> None:
        memory = memory or {}
        n = state.n
        order = memory.get("order")
        if order is not None:
            order = np.asarray(order)
            if order.shape != (n,) or order.dtype.kind not in "iu" or not np.array_equal(np.sort(order), np.arange(n)):
                raise ParameterError("resume: the checkpoint's particle order is not a permutation of the particles")
            order = order.astype(self._ids.dtype)
            # in the saved order; the stable sort below then keeps it exactly
            pos, head = state.positions[order].T, state.headings[order].T
            spd = state.speeds[order] if self._spd.shape[0] > 1 else self._tmp_spd
        else:
            order = np.arange(n, dtype=self._ids.dtype)
            # the kernels read the (N, d) arrays through transposed views: no copies
            pos, head = state.positions.T, state.headings.T
            spd = np.ascontiguousarray(state.speeds) if self._spd.shape[0] > 1 else self._tmp_spd
        _cells(pos, self._nc, self._nc / self._box, self._cell)
        self._sort_into(pos, head, spd, order, self._spd, self._ids)
        if "ring" in memory:
            self._ring[:] = memory["ring"]
        elif self.model.delay:
            self._prime_delay()

    def _sort_into(self, pos, head, spd, ids, spd2, ids2) -> None:
        """Sort by ``self._cell`` into ``self._pos``, ``self._head``, ``spd2`` and ``ids2``."""
        hist = self._hist[: max(1, min(numba.get_num_threads(), self._hist.shape[0]))]
        _sort(self._cell, hist, self._start)
        _scatter(self._cell, hist, pos, head, spd, ids, self._pos, self._head, spd2, ids2)

    def _scratch(self) -> tuple[np.ndarray, np.ndarray]:
        """The spare half of the double buffer ``(new_pos, new_head)``: written by a step,
        free between steps."""
        if self._spare is None:
            self._spare = np.empty_like(self._pos), np.empty_like(self._head)
        return self._spare

    def _prime_delay(self) -> None:
        """Fill every ring slot with the current sums: the initial state stands in for the past."""
        self._ring[:] = self.neighbour_sums()[None]

    def neighbour_sums(self) -> np.ndarray:
        """Per particle id, the neighbours' heading sum (the particle itself left out) and
        ``1 +`` their count, for the current state: shape ``(N, d + 1)``."""
        d, n = self._pos.shape
        ring = np.zeros((1, n, d + 1))
        params = self._params.copy()
        params[5] = 1.0  # record the sums in a one-slot ring; the step itself is thrown away
        self._kernel(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
                     *self._scratch(), self._cell.copy(), ring, 0,
                     self._step_count, self._seed, params, self._partial.copy(), numba.get_num_threads(),
                     *self._extensions)
        return ring[0]

    @property
    def step(self) -> int:
        return self._step_count

    @property
    def state(self) -> State:
        d, n = self._pos.shape
        pos, head = np.empty((n, d)), np.empty((n, d))
        pos[self._ids], head[self._ids] = self._pos.T, self._head.T
        if self._spd.shape[0] == n and n > 1:
            spd = np.empty(n)
            spd[self._ids] = self._spd
        else:
            spd = np.broadcast_to(self._spd[0] if n else 0.0, (n,))
        return State(pos, head, spd, self._step_count)

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities as GSD frames hold them: float32 ``(N, 3)`` in
        particle-id order, z = 0 in 2D (what :func:`flocking.state.frame_arrays` gives).

        They live in the spare half of the double buffer (``2 x d x N`` doubles, room for
        both), so a frame costs no memory; they are valid until the next :meth:`advance`.
        """
        n = self._pos.shape[1]
        new_pos, new_head = self._scratch()
        points = new_pos.reshape(-1).view(np.float32)[: 3 * n].reshape(n, 3)
        velocities = new_head.reshape(-1).view(np.float32)[: 3 * n].reshape(n, 3)
        _frame(self._pos, self._head, self._spd, self._ids, self._box, points, velocities)
        return points, velocities

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each (and keep the moment
        sums of each step in :attr:`moments`)."""
        d, n = self._pos.shape
        phi = np.empty(steps)
        self.moments = moments = np.empty((steps, moment_width(self.model)))
        delay, species = self.model.delay, len(self.model.species_counts)
        new_pos, new_head = self._scratch()
        for t in range(steps):
            slot = self._step_count % delay if delay else 0
            self._kernel(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
                         new_pos, new_head, self._cell, self._ring, slot, self._step_count,
                         self._seed, self._params, self._partial, numba.get_num_threads(), *self._extensions)
            self._sort_into(new_pos, new_head, self._spd, self._ids, self._tmp_spd, self._tmp_ids)
            self._spd, self._tmp_spd = self._tmp_spd, self._spd
            self._ids, self._tmp_ids = self._tmp_ids, self._ids
            self._step_count += 1
            if self._extensions:
                moments[t] = self._partial.sum(axis=0)
                total = moments[t, : d * species].reshape(species, d).sum(axis=0)
            else:
                total = self._partial.sum(axis=0) if n else np.zeros(3)
                moments[t] = total[:d]
            phi[t] = math.sqrt(float(total @ total)) / max(n, 1)
        return phi
