"""The physics of one step, written once: the heading update and what a neighbour adds.

Plain scalar functions that :func:`flocking.rules.compile` builds for the CPU and CUDA
kernels, in the order of docs/model.md. Constants are module globals (``ZERO``, ``ONE``,
..., ``REAL``) that the compiler binds to the target's float type; random numbers come
from :func:`flocking.rng.draw`. A kernel passes literal zeros (no field; no turn: its sine 0) or a
flag it fixes at compile time where a model leaves an extension off, and the compiler
then folds that code away: the plain model runs the plain arithmetic.

>>> from flocking.rules import compile
>>> R = compile("cpu")
>>> ux, uy = R.update_2d(1.0, 0.0, 0.0, 3.0, 3.0, 1.0, 0.0, False, 7, 0, 0, 0.0, 0.0, 0.0, 1.0, 0.0)  # no noise
>>> round(ux, 12), round(uy, 12)
(0.0, 1.0)
"""

import math

from ..rng import NOISE, draw

REAL = float
ZERO, ONE, HALF, TWO, FOUR = 0.0, 1.0, 0.5, 2.0, 4.0
TWO_PI, TINY, NEAR_X = 2.0 * math.pi, 1e-12, 0.9

#: the switches of the pair terms: compile-time constants that :func:`flocking.rules.compile`
#: binds to a kernel's :class:`~flocking.backends.features.Features` (each field in capitals)
NEMATIC = CONE = COHESION = False
#: the values the pair terms read, in the order of the tuple ``pair`` that :func:`neighbour`
#: takes (a kernel reads it once from ``Tables.pair``): the nematic ``bias``, the vision
#: ``cone``, cohesion's ``r_c^2``, ``r_e``, ``r_a`` and slope
PAIR = ("bias", "cone", "rc2", "re", "ra", "slope")

#: the functions of this module that the compiler builds, callees first
RULES = ("greater", "turn", "update_2d", "update_3d", "species_of", "sees", "pair_values", "cone_of",
         "cohesion_term", "neighbour", "cohesive_sum", "nematic_2d", "nematic_3d")
#: the rules numba inlines into their callers (:func:`flocking.rules.compile` says which)
INLINED = ("update_2d", "update_3d", "species_of", "pair_values")


def greater(a, b):
    """``max(a, b)`` as Python's (``a`` unless ``b`` is larger); CUDA has no builtin."""
    return b if b > a else a


def turn(x, y, c, s):
    """The vector ``(x, y)`` turned by the angle whose cosine is ``c`` and sine ``s``."""
    return x * c - y * s, x * s + y * c


def update_2d(ux, uy, sx, sy, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, cturn, sturn):
    """From ``u_i(t)``, the sum ``S_i`` and its number of terms to ``u_i(t+1)`` (2D):
    field ``h g``, vectorial noise, mean direction, alignment by ``epsilon``, chirality
    (the turn ``omega dt`` by its cosine ``cturn`` and sine ``sturn``: constants of a
    species, computed once rather than for every particle and step), angular noise
    ``eta`` (docs/model.md, steps 3 to 6)."""
    z0 = REAL(draw(seed, step, pid, NOISE))
    if h != ZERO:
        sx = sx + h * count * gx
        sy = sy + h * count * gy
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
        wx, wy = turn(ux, uy, math.cos(a), math.sin(a))
    if sturn != ZERO:
        wx, wy = turn(wx, wy, cturn, sturn)
    if not vectorial:
        a = eta * (z0 - HALF)
        wx, wy = turn(wx, wy, math.cos(a), math.sin(a))
    norm = math.sqrt(wx * wx + wy * wy)
    return wx / norm, wy / norm


def update_3d(ux, uy, uz, sx, sy, sz, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, gz):
    """:func:`update_2d` in 3D (no chirality): the cap of angular noise sampled in the
    frame of the aligned heading."""
    z0 = REAL(draw(seed, step, pid, NOISE))
    z1 = REAL(draw(seed, step, pid, NOISE + 1))
    if h != ZERO:
        sx = sx + h * count * gx
        sy = sy + h * count * gy
        sz = sz + h * count * gz
    if vectorial:
        z = TWO * z0 - ONE
        rho = math.sqrt(greater(ZERO, ONE - z * z))
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
        sin_b = math.sqrt(greater(ZERO, ONE - cos_b * cos_b))
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



def species_of(pid, bounds, count):
    """The species of particle ``pid``: species are contiguous id ranges, species ``s``
    from ``bounds[s]`` to ``bounds[s + 1]`` (the last bound is ``N``); ``count`` species
    (``bounds`` has ``count + 1`` entries): a kernel that knows it when it is compiled
    passes it as a constant, and its loop unrolls."""
    s = 0
    while s + 1 < count and pid >= bounds[s + 1]:
        s += 1
    return s


def sees(a, d2, cone):
    """Whether a neighbour at squared distance ``d2`` with ``a = u_i . r_ij`` lies in the
    vision cone, ``u_i . r >= |r| cos(theta)``: written ``a |a| >= cone d2`` with
    ``cone = cos(theta) |cos(theta)|``, which needs no square root; ``cone = -4`` sees
    all around (``a |a| >= -d2`` for a unit ``u``)."""
    return a * abs(a) >= cone * d2


def pair_values(table):
    """The pair terms' values (:data:`PAIR`) from their table, as a tuple of scalars: a
    kernel reads them once, and the compiler keeps them in registers."""
    return table[0], table[1], table[2], table[3], table[4], table[5]


def cone_of(pair):
    """The vision cone's value in the pair terms' values ``pair`` (:data:`PAIR`)."""
    return pair[1]


def cohesion_term(dx, dy, dz, d2, inside, pair):
    """What a neighbour at ``r = (dx, dy, dz)``, ``d2 = |r|^2``, adds to cohesion when
    ``inside`` (counted: within reach and seen): its pull ``f(|r|) r / |r|`` with
    ``f = (|r| - r_e) slope`` below ``r_a`` (``slope = 1 / (4 (r_a - r_e))``: repulsive
    below ``r_e``) and 1 from ``r_a`` on; or, inside the hard core ``0 < |r| < r_c``
    (``rc2 = r_c^2``), its push ``-r / |r|`` and a count of 1 (``rc2``, ``r_e``, ``r_a``
    and the slope are read from ``pair``, :data:`PAIR`). Returns ``(pull, push, count)``
    as seven numbers. A particle at distance 0 (itself, or one on top of it) adds
    nothing. No branch: the CPU kernels sum it in SIMD lanes."""
    bias, cone, rc2, re, ra, slope = pair
    r = math.sqrt(d2)
    inv = ONE / (r if r > ZERO else ONE)  # divided whatever r is: a select, not a branch
    core = inside & (d2 < rc2) & (r > ZERO)
    pull = inside & (d2 >= rc2)
    f = (r - re) * slope if r < ra else ONE
    g = (f * inv) * (ONE if pull else ZERO)
    h = inv * (ONE if core else ZERO)
    return g * dx, g * dy, g * dz, -(h * dx), -(h * dy), -(h * dz), ONE if core else ZERO


def neighbour(dim, dx, dy, dz, d2, inside, ux, uy, uz, vx, vy, vz, coupling, pair):
    """What a candidate neighbour adds to a particle's sums (docs/model.md, steps 1 and 2
    with the extensions): the particle has heading ``u``, the candidate heading ``v``, at
    ``r = (dx, dy, dz)`` from it, ``d2 = |r|^2``; ``inside`` says whether the
    neighbourhood rule admits it (within ``R``, or among the k nearest); ``pair`` holds
    the pair terms' values (:data:`PAIR`).

    It counts only if also in the vision cone (``CONE``: :func:`sees`). Its heading is
    weighed by ``J c``: ``coupling``, the coupling of the two species (1 without a
    matrix), and with ``NEMATIC`` alignment ``c = -1`` where the headings point apart
    (``u . v + bias < 0``; ``c = 1`` at 0): ``bias`` is 0, or 4 in a kernel that compiles
    nematic alignment in for a model without it (``u . v >= -1``: no sign flips). With
    ``COHESION``, it adds :func:`cohesion_term`.
    Returns ``(J c v (3), counted (0 or 1), pull (3), push (3), core count)``
    (:data:`flocking.rules.step.SUMS`); the z entries are 0 in 2D. ``dim`` and the
    switches (``NEMATIC``, ``CONE``, ``COHESION``: the kernel's
    :class:`~flocking.backends.features.Features`, bound by :func:`flocking.rules.compile`)
    are compile-time constants, which fold away what they leave out; no other branch, so
    the CPU sums it in SIMD lanes."""
    bias, cone, rc2, re, ra, slope = pair
    if CONE:
        a = ux * dx + uy * dy
        if dim == 3:
            a += uz * dz
        inside = inside & sees(a, d2, cone)
    n = ONE if inside else ZERO
    w = n * coupling
    if NEMATIC:
        dot = ux * vx + uy * vy + bias
        if dim == 3:
            dot += uz * vz
        w = w * (-ONE if dot < ZERO else ONE)
    px = py = pz = qx = qy = qz = q = ZERO
    if COHESION:
        px, py, pz, qx, qy, qz, q = cohesion_term(dx, dy, dz, d2, inside, pair)
    wz = vz * w if dim == 3 else ZERO
    return vx * w, vy * w, wz, n, px, py, pz, qx, qy, qz, q


def cohesive_sum(sx, sy, sz, px, py, pz, qx, qy, qz, q, beta):
    """The heading sum with cohesion: ``S + beta * pull``, or, when ``q`` neighbours are
    inside the hard core, their push alone (the limit ``f = -inf`` of Gregoire and
    Chate). Returns the sum and whether the core decided it (then neither the field nor
    vectorial noise, finite beside an infinite repulsion, is added)."""
    if q > ZERO:
        return qx, qy, qz, True
    return sx + beta * px, sy + beta * py, sz + beta * pz, False


def nematic_2d(wx, wy):
    """The nematic moments of a heading in 2D: ``ux^2 - uy^2`` and ``2 ux uy``."""
    return wx * wx - wy * wy, TWO * wx * wy


def nematic_3d(wx, wy, wz):
    """The nematic moments of a heading in 3D: ``u_a u_b`` for xx, yy, zz, xy, xz, yz."""
    return wx * wx, wy * wy, wz * wz, wx * wy, wx * wz, wy * wz
