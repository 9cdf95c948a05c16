"""The default backend: numba kernels over cell lists, multi-threaded and deterministic.

Layout. The particle arrays (positions, headings, speeds, ids) are kept in *cell order*:
after every step a stable counting sort by cell reorders them, so the particles of one
cell, and of a row of cells, are contiguous in memory and neighbour loops read them
nearly sequentially. ``ids`` maps a slot back to the particle, which keys the random
numbers and the delay buffer and gives the user the id order back.

Determinism. The sorted order is by cell, then by particle id within a cell: a pure
function of the state, so neither the thread count nor a restart from a checkpoint changes
the order in which neighbours are added. Random numbers are counter-based and the polar
order is summed in fixed blocks. No result depends on the number of threads.

Cells. Metric neighbours use cells at least ``R`` wide, at most about one per particle;
an axis with fewer than three cells visits each of its cells once and takes the minimum
image per pair, so boxes smaller than ``3R`` never count a particle twice. Topological
neighbours search rings of cells outward until the k-th distance is inside the searched
region.

Delay. The sum of the neighbours' headings (without the particle itself) and their count
at step ``t`` is exactly what step ``t + tau`` needs: a ring buffer of ``tau`` such sums,
indexed by particle id, replaces a second neighbour search.

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

import numba
import numpy as np

from ..model import Model
from ..state import State
from .kernels import minimum_image, update_2d, update_3d, wrap

_BLOCK = 1024  # particles per block of the parallel loops; fixed, so results do not depend on threads


def cell_grid(model: Model) -> np.ndarray:
    """Cells per axis: at least ``R`` wide (metric), at most about one per particle."""
    box = np.asarray(model.box, dtype=np.float64)
    if model.neighbours == "metric":
        nc = np.floor(box / model.radius)
        cap = max(model.n, 1)
    else:
        # about 2(k+1) particles in the 3^d block around a cell
        per_cell = max(2.0 * (model.k + 1) / 3**model.dim, 0.5)
        nc = np.floor(box / (per_cell / model.density) ** (1.0 / model.dim))
        cap = max(model.n, 1)
    nc = np.maximum(nc, 1.0)
    total = np.prod(nc)
    if total > cap:
        nc = np.maximum(np.floor(nc * (cap / total) ** (1.0 / model.dim)), 1.0)
    return nc.astype(np.int64)


@numba.njit(cache=True)
def _cell_of(pos, i, nc, inv):
    """Row-major cell index with x fastest, so a row of cells is contiguous."""
    c = 0
    for a in range(pos.shape[1] - 1, -1, -1):
        ca = int(pos[i, a] * inv[a])
        if ca >= nc[a]:
            ca = nc[a] - 1
        c = c * nc[a] + ca
    return c


@numba.njit(cache=True, parallel=True)
def _cells(pos, nc, inv, out):
    for i in numba.prange(pos.shape[0]):
        out[i] = _cell_of(pos, i, nc, inv)


@numba.njit(cache=True)
def _order(cell, ncells, start, order):
    """Stable counting sort: ``start`` (ncells+1) and ``order[slot] = old index``."""
    start[:] = 0
    for i in range(cell.shape[0]):
        start[cell[i] + 1] += 1
    for c in range(ncells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    for i in range(cell.shape[0]):
        c = cell[i]
        order[fill[c]] = i
        fill[c] += 1


@numba.njit(cache=True, parallel=True)
def _by_id_within_cells(order, start, ids):
    """Sort each cell's slots by particle id: the order becomes a pure function of the state,
    so a run continued from a checkpoint adds neighbours in the same order as one that never
    stopped."""
    for c in numba.prange(start.shape[0] - 1):
        for s in range(start[c] + 1, start[c + 1]):
            o = order[s]
            key = ids[o]
            t = s
            while t > start[c] and ids[order[t - 1]] > key:
                order[t] = order[t - 1]
                t -= 1
            order[t] = o


@numba.njit(cache=True, parallel=True)
def _gather(order, pos, head, spd, ids, pos2, head2, spd2, ids2):
    d = pos.shape[1]
    for s in numba.prange(order.shape[0]):
        i = order[s]
        for a in range(d):
            pos2[s, a] = pos[i, a]
            head2[s, a] = head[i, a]
        spd2[s] = spd[i]
        ids2[s] = ids[i]


# -- neighbour sums -------------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _axis_cells(c, n):
    """First neighbour offset and number of distinct neighbour cells along an axis."""
    if n >= 3:
        return c - 1, 3
    return 0, n  # absolute cells 0..n-1, each once


@numba.njit(cache=True)
def _metric_sums_2d(i, pos, head, start, nc, box, half, r2):
    xi, yi = pos[i, 0], pos[i, 1]
    cx = min(int(xi * nc[0] / box[0]), nc[0] - 1)
    cy = min(int(yi * nc[1] / box[1]), nc[1] - 1)
    ox0, nx = _axis_cells(cx, nc[0])
    oy0, ny = _axis_cells(cy, nc[1])
    sx = 0.0
    sy = 0.0
    count = 0
    for oy in range(ny):
        gy = oy0 + oy
        shy = 0.0
        if nc[1] >= 3:
            if gy < 0:
                gy += nc[1]
                shy = box[1]
            elif gy >= nc[1]:
                gy -= nc[1]
                shy = -box[1]
        for ox in range(nx):
            gx = ox0 + ox
            shx = 0.0
            if nc[0] >= 3:
                if gx < 0:
                    gx += nc[0]
                    shx = box[0]
                elif gx >= nc[0]:
                    gx -= nc[0]
                    shx = -box[0]
            c = gy * nc[0] + gx
            for j in range(start[c], start[c + 1]):
                if j == i:
                    continue
                if nc[0] >= 3:
                    dx = (pos[j, 0] - xi) - shx
                else:
                    dx = minimum_image(pos[j, 0] - xi, box[0], half[0])
                if nc[1] >= 3:
                    dy = (pos[j, 1] - yi) - shy
                else:
                    dy = minimum_image(pos[j, 1] - yi, box[1], half[1])
                if dx * dx + dy * dy < r2:
                    sx += head[j, 0]
                    sy += head[j, 1]
                    count += 1
    return sx, sy, count


@numba.njit(cache=True)
def _metric_sums_3d(i, pos, head, start, nc, box, half, r2):
    xi, yi, zi = pos[i, 0], pos[i, 1], pos[i, 2]
    cx = min(int(xi * nc[0] / box[0]), nc[0] - 1)
    cy = min(int(yi * nc[1] / box[1]), nc[1] - 1)
    cz = min(int(zi * nc[2] / box[2]), nc[2] - 1)
    ox0, nx = _axis_cells(cx, nc[0])
    oy0, ny = _axis_cells(cy, nc[1])
    oz0, nz = _axis_cells(cz, nc[2])
    sx = 0.0
    sy = 0.0
    sz = 0.0
    count = 0
    for oz in range(nz):
        gz = oz0 + oz
        shz = 0.0
        if nc[2] >= 3:
            if gz < 0:
                gz += nc[2]
                shz = box[2]
            elif gz >= nc[2]:
                gz -= nc[2]
                shz = -box[2]
        for oy in range(ny):
            gy = oy0 + oy
            shy = 0.0
            if nc[1] >= 3:
                if gy < 0:
                    gy += nc[1]
                    shy = box[1]
                elif gy >= nc[1]:
                    gy -= nc[1]
                    shy = -box[1]
            for ox in range(nx):
                gx = ox0 + ox
                shx = 0.0
                if nc[0] >= 3:
                    if gx < 0:
                        gx += nc[0]
                        shx = box[0]
                    elif gx >= nc[0]:
                        gx -= nc[0]
                        shx = -box[0]
                c = (gz * nc[1] + gy) * nc[0] + gx
                for j in range(start[c], start[c + 1]):
                    if j == i:
                        continue
                    if nc[0] >= 3:
                        dx = (pos[j, 0] - xi) - shx
                    else:
                        dx = minimum_image(pos[j, 0] - xi, box[0], half[0])
                    if nc[1] >= 3:
                        dy = (pos[j, 1] - yi) - shy
                    else:
                        dy = minimum_image(pos[j, 1] - yi, box[1], half[1])
                    if nc[2] >= 3:
                        dz = (pos[j, 2] - zi) - shz
                    else:
                        dz = minimum_image(pos[j, 2] - zi, box[2], half[2])
                    if dx * dx + dy * dy + dz * dz < r2:
                        sx += head[j, 0]
                        sy += head[j, 1]
                        sz += head[j, 2]
                        count += 1
    return sx, sy, sz, count


@numba.njit(cache=True)
def _topological(i, pos, ids, start, nc, box, half, k, best_d2, best_id, best_slot):
    """The k nearest others of slot ``i`` into ``best_slot``; returns how many were found.

    Rings of cells (Chebyshev distance r in cell offsets) are searched outward until the
    k-th distance is below the distance to any unsearched cell. Ties go to the lower id.
    """
    d = pos.shape[1]
    cell = np.empty(3, dtype=np.int64)
    lo = np.zeros(3, dtype=np.int64)
    hi = np.zeros(3, dtype=np.int64)
    width = np.inf
    for a in range(3):
        if a < d:
            cell[a] = min(int(pos[i, a] * nc[a] / box[a]), nc[a] - 1)
            lo[a] = (nc[a] - 1) // 2
            hi[a] = nc[a] - 1 - lo[a]
            width = min(width, box[a] / nc[a])
        else:
            cell[a] = 0
    rmax = 0
    for a in range(d):
        rmax = max(rmax, lo[a], hi[a])
    found = 0
    r = 0
    while True:
        b0 = (-min(r, lo[0]), min(r, hi[0]))
        b1 = (-min(r, lo[1]), min(r, hi[1]))
        b2 = (-min(r, lo[2]), min(r, hi[2]))
        for o0 in range(b0[0], b0[1] + 1):
            for o1 in range(b1[0], b1[1] + 1):
                for o2 in range(b2[0], b2[1] + 1):
                    if max(abs(o0), abs(o1), abs(o2)) != r:
                        continue
                    g0 = (cell[0] + o0) % nc[0]
                    g1 = (cell[1] + o1) % nc[1]
                    if d == 2:
                        c = g1 * nc[0] + g0
                    else:
                        c = (((cell[2] + o2) % nc[2]) * nc[1] + g1) * nc[0] + g0
                    for j in range(start[c], start[c + 1]):
                        if j == i:
                            continue
                        d2 = 0.0
                        for a in range(d):
                            dx = minimum_image(pos[j, a] - pos[i, a], box[a], half[a])
                            d2 += dx * dx
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
        if found == k and best_d2[k - 1] < (r * width) ** 2:
            break
        r += 1
    return found


# -- one step -------------------------------------------------------------------------


@numba.njit(cache=True, parallel=True)
def _step(pos, head, spd, ids, start, nc, box, cell, new_pos, new_head, ring, slot, step, p):
    """One step from the sorted arrays into ``new_*``; ``cell`` gets each new cell.

    ``p`` packs the scalar parameters: r2, k (0 for metric), eta, vectorial, epsilon,
    delay, dt, backward, seed.
    """
    n, d = pos.shape
    r2, k, eta, vectorial, epsilon = p[0], int(p[1]), p[2], p[3] != 0.0, p[4]
    delay, dt, backward, seed = int(p[5]), p[6], p[7] != 0.0, np.uint64(p[8])
    half = box / 2.0
    inv = nc / box
    nblocks = (n + _BLOCK - 1) // _BLOCK
    for b in numba.prange(nblocks):
        best_d2 = np.empty(max(k, 1))
        best_id = np.empty(max(k, 1), dtype=np.int64)
        best_slot = np.empty(max(k, 1), dtype=np.int64)
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            sz = 0.0
            count = 0
            if k == 0:
                if d == 2:
                    sx, sy, count = _metric_sums_2d(i, pos, head, start, nc, box, half, r2)
                else:
                    sx, sy, sz, count = _metric_sums_3d(i, pos, head, start, nc, box, half, r2)
            else:
                count = _topological(i, pos, ids, start, nc, box, half, k, best_d2, best_id, best_slot)
                sx = 0.0
                sy = 0.0
                for q in range(count):
                    j = best_slot[q]
                    sx += head[j, 0]
                    sy += head[j, 1]
                    if d == 3:
                        sz += head[j, 2]
            pid = ids[i]
            total = 1.0 + count
            if delay > 0:
                # this slot holds the sums of `delay` steps ago: read them, then store today's
                osx, osy, osz, ototal = ring[slot, pid, 0], ring[slot, pid, 1], 0.0, ring[slot, pid, d]
                if d == 3:
                    osz = ring[slot, pid, 2]
                    ring[slot, pid, 2] = sz
                ring[slot, pid, 0], ring[slot, pid, 1], ring[slot, pid, d] = sx, sy, total
                sx, sy, sz, total = osx, osy, osz, ototal
            if d == 2:
                ux, uy = head[i, 0], head[i, 1]
                wx, wy = update_2d(ux, uy, ux + sx, uy + sy, total, epsilon, eta, vectorial, seed, step, pid)
                new_head[i, 0], new_head[i, 1] = wx, wy
                if not backward:
                    wx, wy = ux, uy
                ds = spd[i] * dt
                new_pos[i, 0] = wrap(pos[i, 0] + ds * wx, box[0])
                new_pos[i, 1] = wrap(pos[i, 1] + ds * wy, box[1])
            else:
                ux, uy, uz = head[i, 0], head[i, 1], head[i, 2]
                wx, wy, wz = update_3d(ux, uy, uz, ux + sx, uy + sy, uz + sz, total,
                                       epsilon, eta, vectorial, seed, step, pid)
                new_head[i, 0], new_head[i, 1], new_head[i, 2] = wx, wy, wz
                if not backward:
                    wx, wy, wz = ux, uy, uz
                ds = spd[i] * dt
                new_pos[i, 0] = wrap(pos[i, 0] + ds * wx, box[0])
                new_pos[i, 1] = wrap(pos[i, 1] + ds * wy, box[1])
                new_pos[i, 2] = wrap(pos[i, 2] + ds * wz, box[2])
            cell[i] = _cell_of(new_pos, i, nc, inv)


@numba.njit(cache=True, parallel=True)
def _heading_sum(head, out):
    """Sum of headings in fixed blocks, then the blocks in order: thread-independent."""
    n, d = head.shape
    nblocks = (n + _BLOCK - 1) // _BLOCK
    partial = np.zeros((nblocks, d))
    for b in numba.prange(nblocks):
        for i in range(b * _BLOCK, min(n, (b + 1) * _BLOCK)):
            for a in range(d):
                partial[b, a] += head[i, a]
    out[:] = 0.0
    for b in range(nblocks):
        for a in range(d):
            out[a] += partial[b, a]


class CPUBackend:
    """Cell lists and numba threads; bitwise reproducible for any ``NUMBA_NUM_THREADS``."""

    name = "cpu"

    @staticmethod
    def bytes_needed(model: Model) -> int:
        """Peak memory of a run: double-buffered sorted arrays, cells, the delay ring, and
        the id-ordered copy a writer takes."""
        d = model.dim
        per_particle = 2 * (2 * d * 8 + 16) + 16 + 8 * model.delay * (d + 1) + (2 * d + 1) * 8 + 24
        return model.n * per_particle + 8 * int(np.prod(cell_grid(model)))

    def __init__(self, model: Model, state: State, memory: dict | None = None):
        self.model = model
        n, d = state.n, state.dim
        self._box = np.asarray(model.box, dtype=np.float64)
        self._nc = cell_grid(model)
        self._ncells = int(np.prod(self._nc))
        self._start = np.zeros(self._ncells + 1, dtype=np.int64)
        self._cell = np.empty(n, dtype=np.int64)
        self._order = np.empty(n, dtype=np.int64)
        self._pos, self._head = np.empty((n, d)), np.empty((n, d))
        self._spd, self._ids = np.empty(n), np.empty(n, dtype=np.int64)
        self._new_pos, self._new_head = np.empty((n, d)), np.empty((n, d))
        self._tmp_spd, self._tmp_ids = np.empty(n), np.empty(n, dtype=np.int64)
        self._step_count = state.step
        self._params = np.array([
            model.radius**2, model.k if model.neighbours == "topological" else 0, model.noise,
            model.noise_type == "vectorial", model.alignment, model.delay, model.dt,
            model.update == "backward", model.seed,
        ], dtype=np.float64)
        if model.seed >= 2**53:
            raise ValueError("seed: the CPU backend takes seeds below 2**53")
        # ring[t % delay, id]: the neighbours' heading sum and 1 + their count at step t
        self._ring = np.zeros((max(model.delay, 1), n if model.delay else 1, d + 1))
        self._load(state, memory)

    def memory(self) -> dict[str, np.ndarray]:
        """What the backend remembers beyond the state: the delay ring, indexed by id."""
        return {"ring": self._ring.copy()} if self.model.delay else {}

    def _load(self, state: State, memory: dict | None) -> None:
        _cells(state.positions, self._nc, self._nc / self._box, self._cell)
        _order(self._cell, self._ncells, self._start, self._order)
        _gather(self._order, state.positions, state.headings, state.speeds,
                np.arange(state.n, dtype=np.int64), self._pos, self._head, self._spd, self._ids)
        if memory:
            self._ring[:] = memory["ring"]
        elif self.model.delay:
            self._prime_delay()

    def _prime_delay(self) -> None:
        """Fill every ring slot with the current sums: the initial state stands in for the past."""
        self._ring[:] = self.neighbour_sums()[None]

    def neighbour_sums(self) -> np.ndarray:
        """Per particle id, the neighbours' heading sum (the particle itself left out) and
        ``1 +`` their count, for the current state: shape ``(N, d + 1)``."""
        n, d = self._pos.shape
        ring = np.zeros((1, n, d + 1))
        params = self._params.copy()
        params[5] = 1.0  # record the sums in a one-slot ring; the step itself is thrown away
        _step(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
              self._cell.copy(), self._new_pos.copy(), self._new_head.copy(), ring, 0,
              self._step_count, params)
        return ring[0]

    @property
    def step(self) -> int:
        return self._step_count

    @property
    def state(self) -> State:
        n, d = self._pos.shape
        pos, head, spd = np.empty((n, d)), np.empty((n, d)), np.empty(n)
        pos[self._ids], head[self._ids], spd[self._ids] = self._pos, self._head, self._spd
        return State(pos, head, spd, self._step_count)

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps; return the polar order after each."""
        n, d = self._pos.shape
        phi = np.empty(steps)
        total = np.empty(d)
        delay = self.model.delay
        for t in range(steps):
            slot = self._step_count % delay if delay else 0
            _step(self._pos, self._head, self._spd, self._ids, self._start, self._nc, self._box,
                  self._cell, self._new_pos, self._new_head, self._ring, slot, self._step_count,
                  self._params)
            _order(self._cell, self._ncells, self._start, self._order)
            _by_id_within_cells(self._order, self._start, self._ids)
            _gather(self._order, self._new_pos, self._new_head, self._spd, self._ids,
                    self._pos, self._head, self._tmp_spd, self._tmp_ids)
            self._spd, self._tmp_spd = self._tmp_spd, self._spd
            self._ids, self._tmp_ids = self._tmp_ids, self._ids
            self._step_count += 1
            _heading_sum(self._head, total)
            phi[t] = math.sqrt(float(total @ total)) / n
        return phi
