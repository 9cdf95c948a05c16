"""The CPU backend's step for a model with extensions: walls, obstacles, species and their
coupling, vision cones, nematic alignment, chirality and fields.

The plain model keeps the kernels of :mod:`flocking.backends.cpu`; a model with any
extension (:attr:`flocking.Model.extended`) takes one of the two steps here instead, over
the same arrays kept in cell order and the same cells (:func:`kernel` picks):

- :func:`step_lines`, metric neighbours on a grid of at least three cells per axis, works
  like the plain ``_step_lines``: a unit (a segment of a line of cells) gathers its
  candidates into one buffer, with each particle's species alongside. Along an axis with
  walls the wrapped copies are shifted by ``2L`` instead of ``L``, out of reach. Without
  pair weights the plain SIMD reductions sum the neighbours; with them (coupling, nematic
  sign, vision cone), :func:`_wreduce_2d` and :func:`_wreduce_3d` weigh each pair in the
  same four lanes, without branches (in 3D, one weight alone in lanes compiled for it:
  :func:`_weighted_3d`). Both count the particle itself, then take it out.
- :func:`step_search`, topological neighbours and small grids, over blocks of slots: each
  particle sums the others in the ``3^d`` cells around its own (metric, every pair by
  minimum image) or in rings of cells (the ``k`` nearest).

Each neighbour is weighted by the coupling of the two species and, for nematic alignment,
by the sign of ``u_i . u_j``; a vision cone drops the neighbours behind. Then the
per-particle update of :mod:`flocking.backends.kernels` (with the species' noise,
alignment, chirality and field strength), the move, the walls and the obstacles, in the
order of the model description (docs/model.md). Work units are fixed and taken from an
atomic counter, so no result depends on the number of threads. Along an axis with walls
there is no minimum image (``half = inf``) and no cell wraps around. Each unit also sums
the moments of its new headings (:mod:`flocking.observables`: per species ``sum u``, and
the nematic products), then units are added in order.

The parameters travel as small arrays: ``half`` (per axis), ``walls`` (0/1 per axis),
``obstacles`` ``(M, d + 1)`` (centre, radius), ``bounds`` (the first id of each species,
then ``N``), ``species`` ``(S, 4)`` (noise, alignment, ``chirality * dt``, field
strength), ``coupling`` ``(S, S)``, ``g`` (3, the field's direction) and ``q`` (coupling
on, nematic, vision cone on, cosine of the vision half-angle).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .cpu import (_ALL, _BLOCK, _SEGMENT, _U1, _axis_cells, _cell_of, _fetch_add, _gather_unit, _ranges, _reduce_2d,
                  _reduce_3d, _swap_delay, _topological, _work_units)
from .kernels import minimum_image, update_2d, update_3d, wrap

_COUPLING, _NEMATIC, _CONE, _COS = 0, 1, 2, 3
#: the extensions (:attr:`flocking.Model.extensions`) that weigh each neighbour pair: with
#: any of them on, :func:`step_lines` weighs each pair (:func:`_wreduce_2d`)
PAIR_WEIGHTS = ("coupling", "nematic alignment", "vision")


def parameters(model) -> tuple:
    """The extension arrays of :func:`step_lines` and :func:`step_search` for ``model``,
    in their argument order (the cuda backend takes its arrays from here too)."""
    d = model.dim
    box = np.asarray(model.box, dtype=np.float64)
    walls = np.asarray(model.walls, dtype=np.int64)
    half = np.where(walls != 0, np.inf, box / 2.0)
    obstacles = np.array([[*o.centre, o.radius] for o in model.obstacles], dtype=np.float64).reshape(-1, d + 1)
    bounds = np.concatenate([[0], np.cumsum(model.species_counts)]).astype(np.int64)
    species = np.array([model.species_values(name) for name in ("noise", "alignment", "chirality", "field_strength")],
                       dtype=np.float64).T.copy()
    species[:, 2] *= model.dt
    count = len(model.species_counts)
    coupling = np.ones((count, count)) if model.coupling is None else np.array(model.coupling, dtype=np.float64)
    g = np.zeros(3)
    if model.field is not None:
        g[:d] = model.field_direction
    q = np.array([name in model.extensions for name in PAIR_WEIGHTS] + [math.cos(model.vision)], dtype=np.float64)
    return half, walls, obstacles, bounds, species, coupling, g, q


@numba.njit(cache=True, inline="always")
def _species_of(pid, bounds):
    s = 0
    while pid >= bounds[s + 1]:
        s += 1
    return s


@numba.njit(cache=True, inline="always")
def _weight(i, j, head, ids, bounds, coupling, q):
    """``J[s_i][s_j] c_ij``: the weight of neighbour ``j`` in the sum of ``i``."""
    w = 1.0
    if q[_COUPLING] != 0.0:
        w = coupling[_species_of(ids[i], bounds), _species_of(ids[j], bounds)]
    if q[_NEMATIC] != 0.0:
        dot = 0.0
        for a in range(head.shape[0]):
            dot += head[a, i] * head[a, j]
        if dot < 0.0:
            w = -w
    return w


@numba.njit(cache=True)
def _metric_others(i, c, pos, head, ids, start, nc, box, half, walls, r2, bounds, coupling, q):
    """The weighted heading sum of slot ``i``'s metric neighbours (itself left out) and
    their number, from the cells around its own (each once; none across a wall)."""
    d = pos.shape[0]
    cone, cos_v = q[_CONE] != 0.0, q[_COS]
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
        g2 = o2 + k2
        if d == 3:
            if walls[2] != 0 and (g2 < 0 or g2 >= nc[2]):
                continue
            g2 %= nc[2]
        for k1 in range(n1):
            g1 = o1 + k1
            if walls[1] != 0 and (g1 < 0 or g1 >= nc[1]):
                continue
            g1 %= nc[1]
            for k0 in range(n0):
                g0 = o0 + k0
                if walls[0] != 0 and (g0 < 0 or g0 >= nc[0]):
                    continue
                g0 %= nc[0]
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
                    if d2 < r2 and (not cone or dot >= math.sqrt(d2) * cos_v):
                        w = _weight(i, j, head, ids, bounds, coupling, q)
                        sx += w * head[0, j]
                        sy += w * head[1, j]
                        if d == 3:
                            sz += w * head[2, j]
                        count += 1
    return sx, sy, sz, count


@numba.njit(cache=True, inline="always")
def _bounce(i, x, u, box, half, walls, obstacles):
    """After a move: wrap periodic axes, fold across walls (the heading's component turned
    into the box), then push out of each obstacle in order to its mirror point (the
    heading reflected if it points inward). ``x`` and ``u`` are updated in place."""
    d = x.shape[0]
    for a in range(d):
        if walls[a] != 0:
            if x[a, i] < 0.0:
                x[a, i] = -x[a, i]
                u[a, i] = abs(u[a, i])
            elif x[a, i] > box[a]:
                x[a, i] = 2.0 * box[a] - x[a, i]
                u[a, i] = -abs(u[a, i])
        else:
            x[a, i] = wrap(x[a, i], box[a])
    for o in range(obstacles.shape[0]):
        r0 = minimum_image(x[0, i] - obstacles[o, 0], box[0], half[0])
        r1 = minimum_image(x[1, i] - obstacles[o, 1], box[1], half[1])
        r2 = minimum_image(x[2, i] - obstacles[o, 2], box[2], half[2]) if d == 3 else 0.0
        d2 = r0 * r0 + r1 * r1
        if d == 3:
            d2 += r2 * r2
        dist = math.sqrt(d2)
        radius = obstacles[o, d]
        if dist < radius:
            if dist > 0.0:
                n0, n1, n2 = r0 / dist, r1 / dist, r2 / dist
            else:
                n0, n1, n2 = -u[0, i], -u[1, i], -u[2, i] if d == 3 else 0.0
            push = 2.0 * radius - dist
            x[0, i] = obstacles[o, 0] + push * n0
            x[1, i] = obstacles[o, 1] + push * n1
            if d == 3:
                x[2, i] = obstacles[o, 2] + push * n2
            for a in range(d):
                if walls[a] == 0:
                    x[a, i] = wrap(x[a, i], box[a])
            dot = u[0, i] * n0 + u[1, i] * n1
            if d == 3:
                dot += u[2, i] * n2
            if dot < 0.0:
                u[0, i] = u[0, i] - 2.0 * dot * n0
                u[1, i] = u[1, i] - 2.0 * dot * n1
                if d == 3:
                    u[2, i] = u[2, i] - 2.0 * dot * n2


@numba.njit(cache=True, inline="always")
def _advance(i, ox, oy, oz, total, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed,
             vectorial, delay, dt, backward, nc, inv, box, half, walls, obstacles, bounds, species, g):
    """Slot ``i``'s new heading and position into ``new_*`` and its new cell into
    ``cell``, from the weighted sum ``o`` of its neighbours' headings (itself left out)
    and ``total``, their number plus one."""
    d, n = pos.shape
    pid = ids[i]
    if delay > 0:
        ox, oy, oz, total = _swap_delay(ring, slot, pid, ox, oy, oz, total, d)
    s = _species_of(pid, bounds)
    eta, epsilon, turn, h = species[s, 0], species[s, 1], species[s, 2], species[s, 3]
    ds = (spd[i] if spd.shape[0] == n else spd[0]) * dt
    if d == 2:
        ux, uy = head[0, i], head[1, i]
        wx, wy = update_2d(ux, uy, ux + ox, uy + oy, total, epsilon, eta, vectorial, seed, step, pid,
                           h, g[0], g[1], turn)
        new_head[0, i], new_head[1, i] = wx, wy
        if backward:
            ux, uy = wx, wy
        new_pos[0, i] = pos[0, i] + ds * ux
        new_pos[1, i] = pos[1, i] + ds * uy
    else:
        ux, uy, uz = head[0, i], head[1, i], head[2, i]
        wx, wy, wz = update_3d(ux, uy, uz, ux + ox, uy + oy, uz + oz, total, epsilon, eta, vectorial, seed, step,
                               pid, h, g[0], g[1], g[2])
        new_head[0, i], new_head[1, i], new_head[2, i] = wx, wy, wz
        if backward:
            ux, uy, uz = wx, wy, wz
        new_pos[0, i] = pos[0, i] + ds * ux
        new_pos[1, i] = pos[1, i] + ds * uy
        new_pos[2, i] = pos[2, i] + ds * uz
    _bounce(i, new_pos, new_head, box, half, walls, obstacles)
    cell[i] = _cell_of(new_pos, i, nc, inv)


@numba.njit(cache=True, inline="always")
def _accumulate(acc, i, new_head, ids, bounds, nematic):
    """Add slot ``i``'s new heading to the moment sums ``acc``: its species' ``sum u``, then
    (nematic alignment) the products of the nematic order."""
    d = new_head.shape[0]
    o = _species_of(ids[i], bounds) * d
    for a in range(d):
        acc[o + a] += new_head[a, i]
    if nematic:
        o = (bounds.shape[0] - 1) * d
        wx, wy = new_head[0, i], new_head[1, i]
        if d == 2:
            acc[o] += wx * wx - wy * wy
            acc[o + 1] += 2.0 * wx * wy
        else:
            wz = new_head[2, i]
            acc[o] += wx * wx
            acc[o + 1] += wy * wy
            acc[o + 2] += wz * wz
            acc[o + 3] += wx * wy
            acc[o + 4] += wx * wz
            acc[o + 5] += wy * wz


@numba.njit(cache=True)
def _wterm_2d(buf, j, last, xi, yi, ux, uy, fn, r2, cs, jr):
    """As :func:`flocking.backends.cpu._term_2d`, candidate ``j`` weighted: 0 unless it is
    in the vision cone of heading ``(ux, uy)`` (``a |a| >= cs d^2`` for ``a = u . r``,
    the cone test squared with its sign: ``cs`` is ``cos |cos|`` of the half-angle, -4
    with no cone), times the coupling in row ``jr`` of the buffer (the couplings of one
    species to each candidate's, laid out by :func:`_gather_rows`), times -1 if
    ``fn`` is 1 (nematic alignment; else 0) and its heading points against ``u``. Selects
    and products, no branch, as there."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    vx = buf[2, j]
    vy = buf[3, j]
    d2 = dx * dx + dy * dy
    a = ux * dx + uy * dy
    inside = (d2 < r2) & (j <= last) & (a * abs(a) >= cs * d2)
    w = buf[jr, j] * (1.0 if inside else 0.0)
    w *= -1.0 if fn * (ux * vx + uy * vy) < 0.0 else 1.0
    return vx * w, vy * w, 1.0 if inside else 0.0


@numba.njit(cache=True)
def _wterm_3d(buf, j, last, xi, yi, zi, ux, uy, uz, fn, r2, cs, first, si):
    """As :func:`_wterm_2d`, in 3D, the coupling in row ``first + si``; a weight given as
    ``None`` (``cs``, ``fn`` or ``first``) is compiled out, so that numba makes one
    version for each pair weight alone (:func:`_weighted_3d`)."""
    dx = buf[0, j] - xi
    dy = buf[1, j] - yi
    dz = buf[2, j] - zi
    vx = buf[3, j]
    vy = buf[4, j]
    vz = buf[5, j]
    d2 = dx * dx + dy * dy + dz * dz
    if cs is None:
        inside = (d2 < r2) & (j <= last)
    else:
        a = ux * dx + uy * dy + uz * dz
        inside = (d2 < r2) & (j <= last) & (a * abs(a) >= cs * d2)
    w = 1.0 if inside else 0.0
    if first is not None:
        w *= buf[np.uint64(first + int(si)), j]
    if fn is not None:
        w *= -1.0 if fn * (ux * vx + uy * vy + uz * vz) < 0.0 else 1.0
    return vx * w, vy * w, vz * w, 1.0 if inside else 0.0


@numba.njit(cache=True)
def _wreduce_2d(buf, ranges, x, y, hx, hy, tag, i0, i1, r2, cs, nematic, out, o):
    """As :func:`flocking.backends.cpu._reduce_2d` (self included, four lanes), each
    candidate weighted by :func:`_wterm_2d`; ``tag`` holds the species of the slots, and
    buffer row ``4 + s`` the coupling of species ``s`` to each candidate."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        ux = hx[i]
        uy = hy[i]
        fn = 1.0 if nematic else 0.0
        jr = np.uint64(4 + int(tag[i]))
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        n0 = n1 = n2 = n3 = 0.0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = _ALL if j < m4 else hi - _U1
                p0, q0, w0 = _wterm_2d(buf, j, last, xi, yi, ux, uy, fn, r2, cs, jr)
                p1, q1, w1 = _wterm_2d(buf, j + _U1, last, xi, yi, ux, uy, fn, r2, cs, jr)
                p2, q2, w2 = _wterm_2d(buf, j + np.uint64(2), last, xi, yi, ux, uy, fn, r2, cs, jr)
                p3, q3, w3 = _wterm_2d(buf, j + np.uint64(3), last, xi, yi, ux, uy, fn, r2, cs, jr)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (n0 + n1) + (n2 + n3)


@numba.njit(cache=True)
def _wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, cs, fn, first, out, o):
    """As :func:`_wreduce_2d`, in 3D, weighted by :func:`_wterm_3d` with the cone ``cs``,
    the nematic factor ``fn`` and the coupling rows from ``first`` on."""
    for i in range(i0, i1):
        xi = x[i]
        yi = y[i]
        zi = z[i]
        ux = hx[i]
        uy = hy[i]
        uz = hz[i]
        si = tag[i]
        a0 = a1 = a2 = a3 = 0.0
        b0 = b1 = b2 = b3 = 0.0
        c0 = c1 = c2 = c3 = 0.0
        n0 = n1 = n2 = n3 = 0.0
        for r in range(ranges.shape[0]):
            lo, hi = np.uint64(ranges[r, 0]), np.uint64(ranges[r, 1])
            m4 = hi - (hi - lo) % np.uint64(4)
            for j in range(lo, hi, np.uint64(4)):
                last = _ALL if j < m4 else hi - _U1
                p0, q0, r0, w0 = _wterm_3d(buf, j, last, xi, yi, zi, ux, uy, uz, fn, r2, cs, first, si)
                p1, q1, r1, w1 = _wterm_3d(buf, j + _U1, last, xi, yi, zi, ux, uy, uz, fn, r2, cs, first, si)
                p2, q2, r2_, w2 = _wterm_3d(buf, j + np.uint64(2), last, xi, yi, zi, ux, uy, uz, fn, r2, cs,
                                            first, si)
                p3, q3, r3, w3 = _wterm_3d(buf, j + np.uint64(3), last, xi, yi, zi, ux, uy, uz, fn, r2, cs,
                                           first, si)
                a0, a1, a2, a3 = a0 + p0, a1 + p1, a2 + p2, a3 + p3
                b0, b1, b2, b3 = b0 + q0, b1 + q1, b2 + q2, b3 + q3
                c0, c1, c2, c3 = c0 + r0, c1 + r1, c2 + r2_, c3 + r3
                n0, n1, n2, n3 = n0 + w0, n1 + w1, n2 + w2, n3 + w3
        out[0, o + i - i0] = (a0 + a1) + (a2 + a3)
        out[1, o + i - i0] = (b0 + b1) + (b2 + b3)
        out[2, o + i - i0] = (c0 + c1) + (c2 + c3)
        out[3, o + i - i0] = (n0 + n1) + (n2 + n3)


@numba.njit(cache=True)
def _weighted_3d(one, buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, cs, nematic, out, o):
    """The weighted sums of slots ``i0:i1`` in 3D. With one pair weight alone (``one``: its
    index in ``q``, the coupling, the nematic sign or the cone; -1 for several), a version
    of :func:`_wreduce_3d` compiled for it, so the others cost nothing per pair. With
    several, every weight is computed (a cone of ``cs = -4`` admits every candidate,
    ``fn = 0`` keeps every sign). The cone alone keeps the sign, with ``fn = 0``: compiled
    without it, LLVM left the loop scalar. In 2D the same versions measured no faster than
    :func:`_wreduce_2d`, which computes all three. The measurements are in
    docs/performance.md."""
    if one == _COUPLING:
        _wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, None, None, 6, out, o)
    elif one == _NEMATIC:
        _wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, None, 1.0, None, out, o)
    elif one == _CONE:
        _wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, cs, 0.0, None, out, o)
    else:
        _wreduce_3d(buf, ranges, x, y, z, hx, hy, hz, tag, i0, i1, r2, cs, 1.0 if nematic else 0.0, 6, out, o)


@numba.njit(cache=True, parallel=True)
def step_lines(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, p, partial,
               threads, half, walls, obstacles, bounds, species, coupling, g, q):
    """One step with extensions for metric neighbours on a grid of at least three cells
    per axis, in the units of :func:`flocking.backends.cpu._step_lines` (segments of lines
    of cells, the candidates gathered into one buffer per unit; across a wall the wrapped
    copies are shifted out of reach); ``partial[u]`` gets unit ``u``'s moment sums.
    Without pair weights (walls, obstacles, speeds and noises of species, chirality, a
    field) the neighbours are summed by the plain kernel's SIMD reductions."""
    d, n = pos.shape
    r2, vectorial = p[0], p[3] != 0.0
    delay, dt, backward = int(p[5]), p[6], p[7] != 0.0
    nematic = q[_NEMATIC] != 0.0
    # pair weights (coupling, nematic sign, cone) need the weighted sums; otherwise the
    # plain model's serve. In 3D one weight alone has sums compiled for it (_weighted_3d).
    on = (q[_COUPLING] != 0.0, nematic, q[_CONE] != 0.0)
    weighted = on[0] or on[1] or on[2]
    one = -1 if on[0] + on[1] + on[2] != 1 else (_COUPLING if on[0] else _NEMATIC if on[1] else _CONE)
    cs = q[_COS] * abs(q[_COS]) if q[_CONE] != 0.0 else -4.0  # -4: every candidate is in
    inv = nc / box
    shifts = box * (1.0 + walls)  # 2L along a wall axis: a wrapped copy is never within R
    nx = nc[0]
    nseg = (nx + _SEGMENT - 1) // _SEGMENT
    nunits = _work_units(nc, n, 0)
    nt = max(1, min(threads, nunits))
    # per slot its species, and (for weighted sums) its coupling from each species: a
    # unit's buffer holds the latter as rows, so a weighted sum reads one row (a load, not a
    # look-up per pair); unweighted sums read none, so none are made or copied
    tag = np.empty(n)
    cols = np.empty((coupling.shape[0] if weighted else 0, n))
    for i in numba.prange(n):
        s = _species_of(ids[i], bounds)
        tag[i] = s
        for a in range(cols.shape[0]):
            cols[a, i] = coupling[a, s]
    counter = np.zeros(1, dtype=np.int64)
    width = partial.shape[1]
    for t in numba.prange(nt):
        x, y, z = pos[0], pos[1], pos[d - 1]
        hx, hy, hz = head[0], head[1], head[d - 1]
        buf = np.empty((2 * d + cols.shape[0], 4096))
        rows = np.empty((3 if d == 2 else 9, 4), dtype=np.int64)
        ranges = np.empty((3 if d == 2 else 9, 2), dtype=np.int64)
        out = np.empty((4, 16))
        acc = np.zeros(width)
        while True:
            u = _fetch_add(counter)
            if u >= nunits:
                break
            line, c0, c1, s0, s1, buf, out = _gather_unit(u, nseg, x, y, z, hx, hy, hz, cols, start, nc, shifts,
                                                          buf, rows, out, d)
            for cx in range(c0, c1):
                c = line * nx + cx
                _ranges(cx, nx, start, rows, ranges)
                if not weighted and d == 2:
                    _reduce_2d(buf, ranges, x, y, start[c], start[c + 1], r2, out, start[c] - s0)
                elif not weighted:
                    _reduce_3d(buf, ranges, x, y, z, start[c], start[c + 1], r2, out, start[c] - s0)
                elif d == 2:
                    _wreduce_2d(buf, ranges, x, y, hx, hy, tag, start[c], start[c + 1], r2, cs, nematic, out,
                                start[c] - s0)
                else:
                    _weighted_3d(one, buf, ranges, x, y, z, hx, hy, hz, tag, start[c], start[c + 1], r2, cs, nematic,
                                 out, start[c] - s0)
            acc[:] = 0.0
            for i in range(s0, s1):
                m = i - s0
                # the sums include the particle itself, with its own species' coupling
                # (ones without a coupling matrix), in its cone, of its own sense: take it out
                w = coupling[int(tag[i]), int(tag[i])]
                ox, oy, total = out[0, m] - w * hx[i], out[1, m] - w * hy[i], out[d, m]
                oz = out[2, m] - w * hz[i] if d == 3 else 0.0
                _advance(i, ox, oy, oz, total, pos, head, spd, ids, new_pos, new_head, cell, ring, slot, step, seed,
                         vectorial, delay, dt, backward, nc, inv, box, half, walls, obstacles, bounds, species, g)
                _accumulate(acc, i, new_head, ids, bounds, nematic)
            partial[u, :] = acc


@numba.njit(cache=True, parallel=True)
def step_search(pos, head, spd, ids, start, nc, box, new_pos, new_head, cell, ring, slot, step, seed, p, partial,
                threads, half, walls, obstacles, bounds, species, coupling, g, q):
    """One step with extensions over blocks of slots: topological neighbours, and metric
    ones on a grid with fewer than three cells along some axis. ``partial[b]`` gets
    block ``b``'s moment sums; the leading arguments are those of
    :func:`flocking.backends.cpu._step_search`."""
    d, n = pos.shape
    r2, k, vectorial = p[0], int(p[1]), p[3] != 0.0
    delay, dt, backward = int(p[5]), p[6], p[7] != 0.0
    cone, cos_v, nematic = q[_CONE] != 0.0, q[_COS], q[_NEMATIC] != 0.0
    inv = nc / box
    ncells = start.shape[0] - 1
    nblocks = _work_units(nc, n, 1)
    nt = max(1, min(threads, nblocks))
    counter = np.zeros(1, dtype=np.int64)
    width = partial.shape[1]
    for t in numba.prange(nt):
        best_d2 = np.empty(max(k, 1))
        best_id = np.empty(max(k, 1), dtype=np.int64)
        best_slot = np.empty(max(k, 1), dtype=np.int64)
        acc = np.zeros(width)
        while True:
            b = _fetch_add(counter)
            if b >= nblocks:
                break
            s0 = b * _BLOCK
            s1 = min(n, s0 + _BLOCK)
            c = np.searchsorted(start, s0, side="right") - 1
            acc[:] = 0.0
            while c < ncells and start[c] < s1:
                for i in range(max(start[c], s0), min(start[c + 1], s1)):
                    if k == 0:
                        ox, oy, oz, count = _metric_others(i, c, pos, head, ids, start, nc, box, half, walls, r2,
                                                           bounds, coupling, q)
                    else:
                        count = _topological(i, c, pos, head, ids, start, nc, box, half, k, best_d2, best_id,
                                             best_slot, cone, cos_v)
                        ox = 0.0
                        oy = 0.0
                        oz = 0.0
                        for m in range(count):
                            j = best_slot[m]
                            w = _weight(i, j, head, ids, bounds, coupling, q)
                            ox += w * head[0, j]
                            oy += w * head[1, j]
                            if d == 3:
                                oz += w * head[2, j]
                    _advance(i, ox, oy, oz, float(count + 1), pos, head, spd, ids, new_pos, new_head, cell, ring,
                             slot, step, seed, vectorial, delay, dt, backward, nc, inv, box, half, walls, obstacles,
                             bounds, species, g)
                    _accumulate(acc, i, new_head, ids, bounds, nematic)
                c += 1
            partial[b, :] = acc


def kernel(mode: int):
    """The step for a model with extensions and its units of work (the ``mode`` of
    :func:`flocking.backends.cpu._work_units`), from the plain model's kernel ``mode``:
    0 (metric neighbours, at least three cells per axis) takes :func:`step_lines`."""
    return (step_lines, 0) if mode == 0 else (step_search, 1)
