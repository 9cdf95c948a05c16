"""CUDA kernels of the GPU backend (numba.cuda), one thread per particle or per cell.

The per-particle arithmetic is :mod:`flocking.backends.kernels` (``update_2d``,
``update_3d``, ``wrap``, ``minimum_image``) transcribed line by line, in the same order of
floating-point operations, and the random numbers are :func:`flocking.rng._uniform` with
the same uint64 arithmetic: in float64 a GPU step matches a CPU or reference step to
rounding. The arithmetic is written once over a scalar type ``real`` (``np.float64`` or
``np.float32``): every constant is a ``real``, so float32 kernels never silently promote
to float64. Only the polar-order sums are always accumulated in float64.

:func:`build` compiles the kernels for one ``(precision, dim, k, block)``; ``k = 0``
means metric neighbours. Kernels, in the order of a step:

``step``
    neighbour sums (row-contiguous cell ranges, or a ring search for the k nearest),
    delay ring, new heading and position into ``new_*`` (same slots), each particle's
    new cell, and a histogram of cells by atomic increments;
``scan`` / ``add``
    exclusive prefix sum of the histogram into the cell starts (block scans, then the
    block totals, recursively);
``scatter`` / ``cell_sort``
    each particle into its cell's range by an atomic decrement, then each cell's range
    sorted by particle id: the order (cell, then id) is a pure function of the state (the
    atomics leave any order), so it depends neither on thread scheduling nor on restarts;
``gather``
    the particle arrays into cell order, with each block's heading sum;
``reduce``
    the block sums, in a fixed order, into one row of the polar-order table.

There is no per-cell capacity: a cell can hold every particle.
"""

from __future__ import annotations

import functools
import math
import types

import numpy as np
from numba import cuda

from .. import rng

_GOLDEN, _M1, _M2 = rng._GOLDEN, rng._M1, rng._M2
_S30, _S27, _S31, _S11 = rng._S30, rng._S27, rng._S31, rng._S11
_INV53 = rng._INV53
_NOISE0 = np.uint64(rng.NOISE)
_NOISE1 = np.uint64(rng.NOISE + 1)


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


@functools.lru_cache(maxsize=None)
def build(precision: str, dim: int, k: int, block: int) -> types.SimpleNamespace:
    """The kernels for one precision (``"float64"``/``"float32"``), dimension, ``k``
    (0: metric) and threads per block (a power of two)."""
    real = np.float64 if precision == "float64" else np.float32
    ZERO, ONE, HALF, TWO, FOUR = real(0.0), real(1.0), real(0.5), real(2.0), real(4.0)
    TWO_PI, TINY, NEAR_X = real(2.0 * math.pi), real(1e-12), real(0.9)
    DIM, K, KA = dim, k, max(k, 1)
    BLOCK = block

    # -- per-particle arithmetic (kernels.py, transcribed) ---------------------------

    @cuda.jit(device=True)
    def minimum_image(dx, length, half):
        if dx > half:
            return dx - length
        if dx < -half:
            return dx + length
        return dx

    @cuda.jit(device=True)
    def wrap(x, length):
        x = x - length * real(math.floor(x / length))
        if x >= length:
            x -= length
        return x

    @cuda.jit(device=True)
    def cell_of(x, inv, nc):
        c = int(x * inv)
        if c >= nc:
            c = nc - 1
        return c

    @cuda.jit(device=True)
    def update_2d(ux, uy, sx, sy, count, epsilon, eta, vectorial, seed, step, pid):
        z0 = real(uniform(seed, step, pid, _NOISE0))
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
        if not vectorial:
            a = eta * (z0 - HALF)
            c, s = math.cos(a), math.sin(a)
            wx, wy = wx * c - wy * s, wx * s + wy * c
        norm = math.sqrt(wx * wx + wy * wy)
        return wx / norm, wy / norm

    @cuda.jit(device=True)
    def update_3d(ux, uy, uz, sx, sy, sz, count, epsilon, eta, vectorial, seed, step, pid):
        z0 = real(uniform(seed, step, pid, _NOISE0))
        z1 = real(uniform(seed, step, pid, _NOISE1))
        if vectorial:
            z = TWO * z0 - ONE
            rho = math.sqrt(max(ZERO, ONE - z * z))
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
            sin_b = math.sqrt(max(ZERO, ONE - cos_b * cos_b))
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
    def metric_sums(i, pos, head, start, nc0, nc1, nc2, inv0, inv1, inv2, l0, l1, l2, r2):
        h0, h1, h2 = l0 / TWO, l1 / TWO, l2 / TWO
        xi, yi = pos[0, i], pos[1, i]
        zi = pos[2, i] if DIM == 3 else ZERO
        cx, cy = cell_of(xi, inv0, nc0), cell_of(yi, inv1, nc1)
        cz = cell_of(zi, inv2, nc2) if DIM == 3 else 0
        a0, a1, sha, b0, b1, shb = x_ranges(cx, nc0, l0)
        sx, sy, sz = ZERO, ZERO, ZERO
        count = 0
        nz = min(nc2, 3) if DIM == 3 else 1
        for oz in range(nz):
            gz, shz = row_of(cz, oz, nc2, l2) if DIM == 3 else (0, ZERO)
            for oy in range(min(nc1, 3)):
                gy, shy = row_of(cy, oy, nc1, l1)
                row = (gz * nc1 + gy) * nc0
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
                        if DIM == 3:
                            if nc2 >= 3:
                                dz = (pos[2, j] - zi) - shz
                            else:
                                dz = minimum_image(pos[2, j] - zi, l2, h2)
                            d2 += dz * dz
                        if d2 < r2:
                            sx += head[0, j]
                            sy += head[1, j]
                            if DIM == 3:
                                sz += head[2, j]
                            count += 1
        return sx, sy, sz, count

    @cuda.jit(device=True)
    def topological(i, pos, ids, start, nc0, nc1, nc2, inv0, inv1, inv2, l0, l1, l2, width,
                    best_d2, best_id, best_slot):
        """The K nearest others of slot ``i`` into ``best_slot`` (as the CPU backend:
        rings of cells outward until the K-th distance is inside the searched region)."""
        h0, h1, h2 = l0 / TWO, l1 / TWO, l2 / TWO
        c0, c1 = cell_of(pos[0, i], inv0, nc0), cell_of(pos[1, i], inv1, nc1)
        c2 = cell_of(pos[2, i], inv2, nc2) if DIM == 3 else 0
        lo0, lo1 = (nc0 - 1) // 2, (nc1 - 1) // 2
        hi0, hi1 = nc0 - 1 - lo0, nc1 - 1 - lo1
        lo2 = (nc2 - 1) // 2 if DIM == 3 else 0
        hi2 = nc2 - 1 - lo2 if DIM == 3 else 0
        rmax = max(max(lo0, hi0), max(max(lo1, hi1), max(lo2, hi2)))
        found = 0
        r = 0
        while True:
            for o0 in range(-min(r, lo0), min(r, hi0) + 1):
                for o1 in range(-min(r, lo1), min(r, hi1) + 1):
                    for o2 in range(-min(r, lo2), min(r, hi2) + 1):
                        if max(abs(o0), max(abs(o1), abs(o2))) != r:
                            continue
                        g0 = (c0 + o0) % nc0
                        g1 = (c1 + o1) % nc1
                        if DIM == 2:
                            c = g1 * nc0 + g0
                        else:
                            c = (((c2 + o2) % nc2) * nc1 + g1) * nc0 + g0
                        for j in range(start[c], start[c + 1]):
                            if j == i:
                                continue
                            dx = minimum_image(pos[0, j] - pos[0, i], l0, h0)
                            d2 = dx * dx
                            dx = minimum_image(pos[1, j] - pos[1, i], l1, h1)
                            d2 += dx * dx
                            if DIM == 3:
                                dx = minimum_image(pos[2, j] - pos[2, i], l2, h2)
                                d2 += dx * dx
                            jid = ids[j]
                            if found == K and (d2 > best_d2[K - 1]
                                               or (d2 == best_d2[K - 1] and jid > best_id[K - 1])):
                                continue
                            p = found if found < K else K - 1
                            while p > 0 and (best_d2[p - 1] > d2
                                             or (best_d2[p - 1] == d2 and best_id[p - 1] > jid)):
                                best_d2[p] = best_d2[p - 1]
                                best_id[p] = best_id[p - 1]
                                best_slot[p] = best_slot[p - 1]
                                p -= 1
                            best_d2[p] = d2
                            best_id[p] = jid
                            best_slot[p] = j
                            if found < K:
                                found += 1
            if r >= rmax:
                break
            reach = real(r) * width
            if found == K and best_d2[K - 1] < reach * reach:
                break
            r += 1
        return found

    # -- one step --------------------------------------------------------------------

    @cuda.jit
    def step(pos, head, spd, ids, start, nc0, nc1, nc2, inv0, inv1, inv2, l0, l1, l2,
             r2, width, eta, vectorial, epsilon, delay, dt, backward, seed, t, ring, slot,
             new_pos, new_head, cell, counts):
        """One step of slot ``i`` into ``new_*[:, i]``; its new cell into ``cell[i]`` and
        the cell histogram ``counts``. ``ring[slot, :, id]`` (delay > 0) holds the
        neighbour sums of ``delay`` steps ago and receives today's."""
        i = cuda.grid(1)
        if i >= pos.shape[1]:
            return
        if K == 0:
            sx, sy, sz, count = metric_sums(i, pos, head, start, nc0, nc1, nc2,
                                            inv0, inv1, inv2, l0, l1, l2, r2)
        else:
            best_d2 = cuda.local.array(KA, real)
            best_id = cuda.local.array(KA, np.int64)
            best_slot = cuda.local.array(KA, np.int64)
            count = topological(i, pos, ids, start, nc0, nc1, nc2, inv0, inv1, inv2,
                                l0, l1, l2, width, best_d2, best_id, best_slot)
            sx, sy, sz = ZERO, ZERO, ZERO
            for q in range(count):
                j = best_slot[q]
                sx += head[0, j]
                sy += head[1, j]
                if DIM == 3:
                    sz += head[2, j]
        pid = ids[i]
        total = ONE + real(count)
        if delay > 0:
            osx, osy, ototal = ring[slot, 0, pid], ring[slot, 1, pid], ring[slot, DIM, pid]
            ring[slot, 0, pid], ring[slot, 1, pid], ring[slot, DIM, pid] = sx, sy, total
            osz = ZERO
            if DIM == 3:
                osz = ring[slot, 2, pid]
                ring[slot, 2, pid] = sz
            sx, sy, sz, total = osx, osy, osz, ototal
        useed, ustep, upid = np.uint64(seed), np.uint64(t), np.uint64(pid)
        ds = spd[i] * dt
        if DIM == 2:
            ux, uy = head[0, i], head[1, i]
            wx, wy = update_2d(ux, uy, ux + sx, uy + sy, total, epsilon, eta, vectorial,
                               useed, ustep, upid)
            new_head[0, i], new_head[1, i] = wx, wy
            if not backward:
                wx, wy = ux, uy
            x = wrap(pos[0, i] + ds * wx, l0)
            y = wrap(pos[1, i] + ds * wy, l1)
            new_pos[0, i], new_pos[1, i] = x, y
            c = cell_of(y, inv1, nc1) * nc0 + cell_of(x, inv0, nc0)
        else:
            ux, uy, uz = head[0, i], head[1, i], head[2, i]
            wx, wy, wz = update_3d(ux, uy, uz, ux + sx, uy + sy, uz + sz, total, epsilon, eta,
                                   vectorial, useed, ustep, upid)
            new_head[0, i], new_head[1, i], new_head[2, i] = wx, wy, wz
            if not backward:
                wx, wy, wz = ux, uy, uz
            x = wrap(pos[0, i] + ds * wx, l0)
            y = wrap(pos[1, i] + ds * wy, l1)
            z = wrap(pos[2, i] + ds * wz, l2)
            new_pos[0, i], new_pos[1, i], new_pos[2, i] = x, y, z
            c = (cell_of(z, inv2, nc2) * nc1 + cell_of(y, inv1, nc1)) * nc0 + cell_of(x, inv0, nc0)
        cell[i] = c
        cuda.atomic.add(counts, c, 1)

    @cuda.jit
    def cells(pos, nc0, nc1, nc2, inv0, inv1, inv2, cell, counts):
        """Cell and histogram of unsorted positions (the initial state)."""
        i = cuda.grid(1)
        if i >= pos.shape[1]:
            return
        c = cell_of(pos[1, i], inv1, nc1) * nc0 + cell_of(pos[0, i], inv0, nc0)
        if DIM == 3:
            c += cell_of(pos[2, i], inv2, nc2) * nc1 * nc0
        cell[i] = c
        cuda.atomic.add(counts, c, 1)

    # -- stable counting sort --------------------------------------------------------

    @cuda.jit
    def scan(data, out, sums):
        """Exclusive prefix sum within each block of ``data`` into ``out`` (may be
        ``data``); each block's total into ``sums``."""
        buf = cuda.shared.array(BLOCK, np.int64)
        i = cuda.grid(1)
        tid = cuda.threadIdx.x
        v = data[i] if i < data.shape[0] else 0
        buf[tid] = v
        cuda.syncthreads()
        offset = 1
        while offset < BLOCK:
            add = buf[tid - offset] if tid >= offset else 0
            cuda.syncthreads()
            buf[tid] += add
            cuda.syncthreads()
            offset *= 2
        if i < data.shape[0]:
            out[i] = buf[tid] - v
        if tid == BLOCK - 1:
            sums[cuda.blockIdx.x] = buf[tid]

    @cuda.jit
    def add(out, sums):
        """Add each block's offset (the scanned block totals) to its part of ``out``."""
        i = cuda.grid(1)
        if i < out.shape[0]:
            out[i] += sums[cuda.blockIdx.x]

    @cuda.jit
    def scatter(cell, start, counts, order):
        """Slot of each particle inside its cell's range; ``counts`` goes back to zero."""
        i = cuda.grid(1)
        if i >= cell.shape[0]:
            return
        c = cell[i]
        order[start[c] + cuda.atomic.add(counts, c, -1) - 1] = i

    @cuda.jit
    def cell_sort(start, order, ids, ncells):
        """Sort each cell's range by particle id (insertion sort: cells are small, and a
        crowded cell only costs time, never correctness)."""
        c = cuda.grid(1)
        if c >= ncells:
            return
        lo, hi = start[c], start[c + 1]
        for a in range(lo + 1, hi):
            v = order[a]
            key = ids[v]
            b = a
            while b > lo and ids[order[b - 1]] > key:
                order[b] = order[b - 1]
                b -= 1
            order[b] = v

    @cuda.jit(device=True)
    def block_sum(buf, tid):
        """Tree sum of the shared ``buf[:, :BLOCK]`` into ``buf[:, 0]``, in a fixed order;
        every thread of the block calls it."""
        cuda.syncthreads()
        stride = BLOCK // 2
        while stride > 0:
            if tid < stride:
                for a in range(DIM):
                    buf[a, tid] += buf[a, tid + stride]
            cuda.syncthreads()
            stride //= 2

    @cuda.jit
    def gather(order, pos, head, spd, ids, pos2, head2, spd2, ids2, partial):
        """``x2[:, s] = x[:, order[s]]``; each block's heading sum (float64) into ``partial``."""
        buf = cuda.shared.array((DIM, BLOCK), np.float64)
        s = cuda.grid(1)
        tid = cuda.threadIdx.x
        for a in range(DIM):
            buf[a, tid] = 0.0
        if s < order.shape[0]:
            i = order[s]
            for a in range(DIM):
                pos2[a, s] = pos[a, i]
                head2[a, s] = head[a, i]
                buf[a, tid] = np.float64(head[a, i])
            spd2[s] = spd[i]
            ids2[s] = ids[i]
        block_sum(buf, tid)
        if tid == 0:
            for a in range(DIM):
                partial[a, cuda.blockIdx.x] = buf[a, 0]

    @cuda.jit
    def reduce(partial, out, row):
        """One block: ``out[row] = sum of partial`` over blocks, in a fixed order."""
        buf = cuda.shared.array((DIM, BLOCK), np.float64)
        tid = cuda.threadIdx.x
        for a in range(DIM):
            acc = 0.0
            for b in range(tid, partial.shape[1], BLOCK):
                acc += partial[a, b]
            buf[a, tid] = acc
        block_sum(buf, tid)
        if tid == 0:
            for a in range(DIM):
                out[row, a] = buf[a, 0]

    return types.SimpleNamespace(
        real=real, step=step, cells=cells, scan=scan, add=add, scatter=scatter,
        cell_sort=cell_sort, gather=gather, reduce=reduce,
    )
