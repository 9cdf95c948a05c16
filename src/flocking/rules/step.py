"""The end of a particle's step, written once: from its neighbour sums to its new heading
and position, and the delay ring that remembers those sums.

The sums of a particle are one tuple of :data:`SUMS` (the others' weighed heading sum, their
count, and with cohesion the pull, the push and the count inside the hard core): both
kernels add candidates' terms into it with :func:`plus` and hand it to :func:`finish`. The
ring ``ring[t % tau, row]`` holds :func:`width` of them (``row``: a particle's id, or its
global id among replicas), written by :func:`keep` and read by :func:`recall`. A new
heading goes into the run's moment sums (its species' polar order, the nematic order) by
:func:`add_moments`.

>>> from flocking.rules import compile
>>> R = compile("cpu")
>>> s = R.plus(R.plus(SUM0, (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)), (0.0, 2.0, 0.0, 1.0) + SUM0[4:])
>>> s[:4]
(1.0, 2.0, 0.0, 2.0)
>>> width(2, False), width(3, True)
(3, 11)
>>> counted(s)[3], with_own(s, -1.0, 1.0, 0.5, 0.0)[:4]
(3.0, (0.0, 1.5, 0.0, 2.0))
"""

from .geometry import fold, push_out_2d, push_out_3d, wrap
from .physics import (
    cohesive_sum,
    nematic_2d,
    nematic_3d,
    species_of,
    update_2d,
    update_3d,
)

REAL = float
ZERO, ONE = 0.0, 1.0

#: what a particle's sums hold, in order: adding a sum is a name here and its term in
#: :func:`flocking.rules.physics.neighbour`
SUMS = ("sx", "sy", "sz", "count", "pull_x", "pull_y", "pull_z", "push_x", "push_y", "push_z", "core")
#: the sums of no candidate (plain floats; the kernels start from them)
SUM0 = (0.0,) * len(SUMS)

#: the functions of this module that the compiler builds, callees first
RULES = ("plus", "counted", "with_own", "finish", "keep", "recall", "add_moments")
#: the rules numba inlines into their callers (:func:`flocking.rules.compile` says which)
INLINED = ("finish", "keep", "recall", "add_moments")


def plus(s, t):
    """``s + t``, sum by sum (:data:`SUMS`)."""
    return (s[0] + t[0], s[1] + t[1], s[2] + t[2], s[3] + t[3], s[4] + t[4], s[5] + t[5], s[6] + t[6],
            s[7] + t[7], s[8] + t[8], s[9] + t[9], s[10] + t[10])


def counted(s):
    """The sums ``s`` with the particle itself counted: one more in the count."""
    return s[:3] + (s[3] + ONE,) + s[4:]


def with_own(s, w, ux, uy, uz):
    """The sums ``s`` with the particle's own heading ``u`` added with weight ``w`` (a
    negative ``w`` takes it out): ``S + w u``. :func:`finish` takes the heading sum with
    the particle's own heading in it, with weight 1; the delay ring keeps it without."""
    return (s[0] + w * ux, s[1] + w * uy, s[2] + w * uz) + s[3:]


def width(dim, cohesion):
    """Values a particle keeps in the delay ring: the heading sum and the count, and with
    cohesion the pull, the push and the core count (plain Python, for allocating)."""
    return dim + 1 + (2 * dim + 1 if cohesion else 0)


def keep(ring, slot, row, s, dim, coh):
    """Store the sums ``s`` in ``ring[slot, row]``: ``S`` (``dim``), the count, then with
    ``coh`` the pull (``dim``), the push (``dim``) and the core count."""
    ring[slot, row, 0] = s[0]
    ring[slot, row, 1] = s[1]
    if dim == 3:
        ring[slot, row, 2] = s[2]
    ring[slot, row, dim] = s[3]
    if coh:
        o = dim + 1
        ring[slot, row, o] = s[4]
        ring[slot, row, o + 1] = s[5]
        ring[slot, row, o + dim] = s[7]
        ring[slot, row, o + dim + 1] = s[8]
        if dim == 3:
            ring[slot, row, o + 2] = s[6]
            ring[slot, row, o + dim + 2] = s[9]
        ring[slot, row, o + 2 * dim] = s[10]


def recall(ring, slot, row, dim, coh):
    """The sums :func:`keep` stored in ``ring[slot, row]`` (zero where it stores none)."""
    x, y = ring[slot, row, 0], ring[slot, row, 1]
    z = ring[slot, row, 2] if dim == 3 else ZERO
    total = ring[slot, row, dim]
    if not coh:
        return x, y, z, total, ZERO, ZERO, ZERO, ZERO, ZERO, ZERO, ZERO
    o = dim + 1
    return (x, y, z, total, ring[slot, row, o], ring[slot, row, o + 1], ring[slot, row, o + 2] if dim == 3 else ZERO,
            ring[slot, row, o + dim], ring[slot, row, o + dim + 1], ring[slot, row, o + dim + 2] if dim == 3 else ZERO,
            ring[slot, row, o + 2 * dim])


def add_moments(acc, col, pid, bounds, count, dim, nematic, wx, wy, wz):
    """Add a new heading ``w`` of particle ``pid`` to the moment sums in column ``col`` of
    ``acc``, in the layout of :func:`flocking.observables.moment_sums`: rows ``dim s`` on
    the heading sum of its species ``s`` (:func:`~flocking.rules.physics.species_of` with
    ``count`` species and ``bounds``), then with ``nematic`` the nematic products
    (:func:`~flocking.rules.physics.nematic_2d`, ``nematic_3d``) from row ``dim count``."""
    row = species_of(pid, bounds, count) * dim if count > 1 else 0
    acc[row, col] += wx
    acc[row + 1, col] += wy
    if dim == 3:
        acc[row + 2, col] += wz
    if nematic:
        row = count * dim
        if dim == 2:
            a, b = nematic_2d(wx, wy)
            acc[row, col] += a
            acc[row + 1, col] += b
        else:
            m = nematic_3d(wx, wy, wz)
            for e in range(6):
                acc[row + e, col] += m[e]


def finish(dim, ext, coh, ux, uy, uz, s, beta, values, vectorial, backward, seed, step, pid, field, ds, x, y, z,
           lengths, half, walls, obstacles, count):
    """From a particle's heading ``u``, its sums ``s`` (:data:`SUMS`, the sum including its
    own heading) and its species' ``values`` (``eta``, ``epsilon``, the field's strength
    ``h``, the cosine and sine of the turn) to its new position and heading, in the order
    of docs/model.md: cohesion (``beta``; a particle whose hard core holds a neighbour gets
    its push alone, and neither the field nor vectorial noise, finite beside an infinite
    repulsion), the update (:func:`~flocking.rules.physics.update_2d`, ``field`` the
    direction ``g``), the move by ``ds`` along the new (``backward``) or the old heading,
    then with ``ext`` the walls (:func:`~flocking.rules.geometry.fold`) and the first
    ``count`` rows of ``obstacles`` (:func:`~flocking.rules.geometry.push_out_2d`), else the
    wrap. ``lengths``, ``half``, ``walls``: the box's sides, half-lengths (infinite along
    walls) and walls, three each. Returns ``x, y, z, wx, wy, wz`` (``z`` as given and
    ``wz`` 0 in 2D)."""
    eta, epsilon, h, cturn, sturn = values
    l0, l1, l2 = lengths
    h0, h1, h2 = half
    w0, w1, w2 = walls
    sx, sy, sz, total = s[0], s[1], s[2], s[3]
    if coh:
        sx, sy, sz, core = cohesive_sum(sx, sy, sz, s[4], s[5], s[6], s[7], s[8], s[9], s[10], beta)
        if core:
            h = ZERO
            if vectorial:
                eta = ZERO
    if dim == 2:
        wx, wy = update_2d(ux, uy, sx, sy, total, epsilon, eta, vectorial, seed, step, pid, h, field[0], field[1],
                           cturn, sturn)
        wz = ZERO
    else:
        wx, wy, wz = update_3d(ux, uy, uz, sx, sy, sz, total, epsilon, eta, vectorial, seed, step, pid, h, field[0],
                               field[1], field[2])
    if backward:
        mx, my, mz = wx, wy, wz
    else:
        mx, my, mz = ux, uy, uz
    x = x + ds * mx
    y = y + ds * my
    if dim == 3:
        z = z + ds * mz
    if not ext:
        x = wrap(x, l0)
        y = wrap(y, l1)
        if dim == 3:
            z = wrap(z, l2)
        return x, y, z, wx, wy, wz
    x, wx = fold(x, wx, l0, w0)
    y, wy = fold(y, wy, l1, w1)
    if dim == 3:
        z, wz = fold(z, wz, l2, w2)
    for o in range(count):
        if dim == 2:
            x, y, wx, wy = push_out_2d(x, y, wx, wy, obstacles[o, 0], obstacles[o, 1], obstacles[o, 2], l0, l1, h0, h1,
                                       w0, w1)
        else:
            x, y, z, wx, wy, wz = push_out_3d(x, y, z, wx, wy, wz, obstacles[o, 0], obstacles[o, 1], obstacles[o, 2],
                                              obstacles[o, 3], l0, l1, l2, h0, h1, h2, w0, w1, w2)
    return x, y, z, wx, wy, wz
