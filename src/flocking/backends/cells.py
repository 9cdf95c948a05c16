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
from llvmlite.binding import llvm_version_info
from numba.core import cgutils, types
from numba.core.codegen import get_host_cpu_features
from numba.extending import intrinsic

from ..model import Model
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


@intrinsic
def fetch_add(typingctx, counter):
    """Atomically ``counter[0] += 1``, returning the old value: hands out work blocks."""
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "monotonic")

    return sig, codegen


@intrinsic
def prefetch(typingctx, ring, slot, pid):
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


@intrinsic
def mask4(typingctx, b0, b1, b2, b3):
    """``b0 + 2 b1 + 4 b2 + 8 b3`` (uint64) from four booleans, built as the bits of one
    vector of four so that LLVM takes it from a vector comparison in one move."""
    sig = types.uint64(types.boolean, types.boolean, types.boolean, types.boolean)

    def codegen(context, builder, signature, args):
        from llvmlite import ir

        vec = ir.Constant(ir.VectorType(ir.IntType(1), 4), None)
        for lane, bit in enumerate(args):
            vec = builder.insert_element(vec, bit, ir.IntType(32)(lane))
        return builder.zext(builder.bitcast(vec, ir.IntType(4)), ir.IntType(64))

    return sig, codegen


#: the forms of :data:`compress4`'s machine code (:func:`compress_ir`)
COMPRESS_FORMS = ("avx512", "avx2", "select")


def compress_form(features: str, llvm: tuple) -> str:
    """The form of :func:`compress_ir` for a target with ``features`` (LLVM's string,
    ``+avx2,-avx512f,...``) and LLVM version ``llvm``: LLVM's own compress where it has it
    (LLVM 19 on) and the target has AVX-512 (one ``vpcompressq``; without AVX-512 LLVM
    expands it through memory: cohesion at 0.50 of the plain rate instead of 0.68 with
    AVX2 code); else a permutation where the target has AVX2 (``vpermd``); else selects.

    >>> compress_form("+avx2,+avx512f,+avx512vl", (22, 1, 0)), compress_form("+avx2,-avx512f", (22, 1, 0))
    ('avx512', 'avx2')
    >>> compress_form("+neon", (20, 1, 0))
    'select'
    """
    on = {f[1:] for f in features.split(",") if f.startswith("+")}
    if llvm >= (19,) and {"avx512f", "avx512vl"} <= on:
        return "avx512"
    return "avx2" if "avx2" in on else "select"


def compress_ir(builder, values, bits, form):
    """LLVM IR for :data:`compress4`: the four doubles ``values`` whose ``bits`` are set,
    moved to the front in order, then zeros, in one of :data:`COMPRESS_FORMS`. All work
    on 64-bit integers (LLVM 22 cannot expand a compress of doubles without AVX-512)."""
    from llvmlite import ir

    i32, i64 = ir.IntType(32), ir.IntType(64)
    vt, mt = ir.VectorType(i64, 4), ir.VectorType(ir.IntType(1), 4)
    vec, mask = ir.Constant(vt, None), ir.Constant(mt, None)
    for lane in range(4):
        vec = builder.insert_element(vec, builder.bitcast(values[lane], i64), i32(lane))
        mask = builder.insert_element(mask, bits[lane], i32(lane))
    if form == "avx512":
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vt, [vt, mt, vt]),
                                            "llvm.experimental.vector.compress.v4i64")
        out = builder.call(fn, [vec, mask, ir.Constant(vt, [0] * 4)])
    else:
        # by the 4-bit mask, a table row: the source lane of each lane of the result, and
        # all ones where a lane holds a value (zeros after the last)
        counts = [bin(m).count("1") for m in range(16)]
        rows = [[lane for lane in range(4) if m >> lane & 1] + [0] * (4 - counts[m]) for m in range(16)]
        keep = table(builder, "flocking_compress_keep", vt, [[-1] * c + [0] * (4 - c) for c in counts])
        m = builder.zext(builder.bitcast(mask, ir.IntType(4)), i64)
        if form == "avx2":  # vpermd: the 32-bit halves of each source lane
            v8 = ir.VectorType(i32, 8)
            halves = [[h for lane in r for h in (2 * lane, 2 * lane + 1)] for r in rows]
            source = builder.load(builder.gep(table(builder, "flocking_compress_halves", v8, halves), [i64(0), m]))
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(v8, [v8, v8]), "llvm.x86.avx2.permd")
            out = builder.bitcast(builder.call(fn, [builder.bitcast(vec, v8), source]), vt)
        else:
            source = builder.load(builder.gep(table(builder, "flocking_compress_lanes", vt, rows), [i64(0), m]))
            out = ir.Constant(vt, [0] * 4)
            for lane in range(4):
                at = ir.Constant(ir.VectorType(i32, 4), [lane] * 4)
                spread = builder.shuffle_vector(vec, ir.Constant(vt, None), at)
                out = builder.select(builder.icmp_unsigned("==", source, ir.Constant(vt, [lane] * 4)), spread, out)
        out = builder.and_(out, builder.load(builder.gep(keep, [i64(0), m])))
    return [builder.bitcast(builder.extract_element(out, i32(lane)), ir.DoubleType()) for lane in range(4)]


def table(builder, name, vt, rows):
    """A constant global array of vectors of type ``vt`` in the module of ``builder``,
    made once per module."""
    from llvmlite import ir

    found = builder.module.globals.get(name)
    if found is None:
        tt = ir.ArrayType(vt, len(rows))
        found = ir.GlobalVariable(builder.module, tt, name)
        found.initializer = ir.Constant(tt, [ir.Constant(vt, row) for row in rows])
        found.global_constant = True
        found.linkage = "internal"
    return found


def compress_intrinsic(form: str):
    """:data:`compress4` in one of :data:`COMPRESS_FORMS` (the tests build each)."""

    @intrinsic
    def compress(typingctx, v0, v1, v2, v3, b0, b1, b2, b3):
        sig = types.UniTuple(types.float64, 4)(*[types.float64] * 4, *[types.boolean] * 4)

        def codegen(context, builder, signature, args):
            return context.make_tuple(builder, signature.return_type, compress_ir(builder, args[:4], args[4:], form))

        return sig, codegen

    return compress


#: the form of :data:`compress4` for the machine numba compiles for
COMPRESS = compress_form(numba.core.config.CPU_FEATURES or get_host_cpu_features(), llvm_version_info)

#: ``compress4(v0, v1, v2, v3, b0, b1, b2, b3)``: those of the four doubles ``v`` whose
#: ``b`` is true, in order, then zeros (a tuple of four), for numba-compiled code, in the
#: form :data:`COMPRESS`. It writes cohesion's noted displacements a
#: group of four at a time: :func:`flocking.backends.cpu_kernels.note`.
compress4 = compress_intrinsic(COMPRESS)


# -- the cell structure: parallel stable counting sort ---------------------------------


@numba.njit(cache=True, inline="always")
def cell_of(pos, i, nc, inv):
    """Row-major cell index of slot ``i`` with x fastest, so a row of cells is contiguous
    (each axis by :func:`flocking.rules.geometry.cell_index`: always a valid cell)."""
    c = 0
    for a in range(pos.shape[0] - 1, -1, -1):
        c = c * nc[a] + R.cell_index(pos[a, i], inv[a], nc[a])
    return c


@numba.njit(cache=True, parallel=True)
def cell_indices(pos, nc, inv, out):
    for i in numba.prange(pos.shape[1]):
        out[i] = cell_of(pos, i, nc, inv)


@numba.njit(cache=True, parallel=True)
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


@numba.njit(cache=True, parallel=True)
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


@numba.njit(cache=True, inline="always")
def neighbour_row(g, n, length):
    """Row/plane ``g`` folded into ``0..n-1`` and the shift to add to a displacement."""
    if g < 0:
        return g + n, -length
    if g >= n:
        return g - n, length
    return g, 0.0


U1 = np.uint64(1)
ALL = np.uint64(2**64 - 1)  # a `last` that masks nothing


@numba.njit(cache=True, inline="always")
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


@numba.njit(cache=True, inline="always")
def neighbour_line(gy, gz, r, nc, box, d):
    """The ``r``-th of the 3 (3D: 9) lines around line ``(gy, gz)``: its first cell and
    the shifts (y, z) to its periodic image nearest that line."""
    hz, shz = neighbour_row(gz + r // 3 - 1, nc[d - 1], box[d - 1]) if d == 3 else (0, 0.0)
    hy, shy = neighbour_row(gy + r % 3 - 1, nc[1], box[1])
    return (hz * nc[1] + hy) * nc[0], shy, shz


@numba.njit(cache=True)
def gather_rows(line, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, box, buf, rows, d):
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


@numba.njit(cache=True, inline="always")
def gather_unit(u, nseg, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, out, d):
    """Unit ``u`` of the line kernels, segment ``u % nseg`` of line ``u // nseg`` (as
    :func:`work_units` counts them): its line, columns ``c0..c1-1`` and slots ``s0..s1-1``,
    with its candidates gathered into ``buf`` (:func:`gather_rows`; ``shifts`` and ``tag``
    as there). Returns those and ``buf`` and ``out`` (sums, a column per slot), each
    replaced by a larger one where the unit needs more room."""
    line = u // nseg
    c0 = (u % nseg) * SEGMENT
    c1 = min(nc[0], c0 + SEGMENT)
    while gather_rows(line, c0, c1, x, y, z, hx, hy, hz, tag, start, nc, shifts, buf, rows, d) < 0:
        buf = np.empty((buf.shape[0], 2 * buf.shape[1]))
    s0, s1 = start[line * nc[0] + c0], start[line * nc[0] + c1]
    if s1 - s0 > out.shape[1]:
        out = np.empty((out.shape[0], 2 * (s1 - s0)))
    return line, c0, c1, s0, s1, buf, out


@numba.njit(cache=True, inline="always")
def candidate_ranges(cx, nx, start, rows, ranges):
    """Where, in the buffer of :func:`gather_rows`, the candidates of column ``cx`` lie:
    one range per neighbouring line, into ``ranges``."""
    for r in range(rows.shape[0]):
        row0, delta = rows[r, 0], rows[r, 3]
        ranges[r, 0] = rows[r, 1] if cx == 0 else start[row0 + cx - 1] + delta
        ranges[r, 1] = rows[r, 2] if cx == nx - 1 else start[row0 + cx + 2] + delta


@numba.njit(cache=True, inline="always")
def axis_cells(c, n):
    """First neighbour offset and number of distinct neighbour cells along an axis."""
    if n >= 3:
        return c - 1, 3
    return 0, n  # absolute cells 0..n-1, each once


@numba.njit(cache=True)
def work_units(nc, n, mode):
    """How many units of work a step is split into: segments of lines of cells for the
    fast metric kernel (mode 0), blocks of slots otherwise. Fixed by the model alone."""
    if mode == 0:
        return (np.prod(nc) // nc[0]) * ((nc[0] + SEGMENT - 1) // SEGMENT)
    return (n + BLOCK - 1) // BLOCK


@numba.njit(cache=True, parallel=True)
def write_frame(pos, head, spd, ids, box, points, velocities):
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


