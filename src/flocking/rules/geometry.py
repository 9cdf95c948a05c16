"""The geometry of the box, written once: wrapping, the minimum image, cells, walls, obstacles.

Plain scalar functions that :mod:`flocking.rules` compiles for every target (numba on the
CPU, CUDA device functions, NumPy ufuncs for :mod:`flocking.space`). They name their
constants (``ZERO``, ``ONE``, ``TWO``, ``INF``) and conversions (``REAL``) as module
globals, which the compiler binds to the target's float type, so that a float32 kernel
never promotes to float64. Run as plain Python they work on floats.

A box side ``L`` along axis ``a`` is periodic (coordinates in ``[0, L)``, displacements
folded into ``[-L/2, L/2]``) or closed by walls (coordinates in ``[0, L]``, no folding:
``half = INF``).

>>> wrap(-0.25, 4.0), wrap(4.0, 4.0), minimum_image(3.0, 4.0, 2.0), minimum_image(3.0, 4.0, INF)
(3.75, 0.0, -1.0, 3.0)
>>> fold(-0.5, -0.8, 4.0, True), fold(4.5, 0.6, 4.0, False)
((0.5, 0.8), (0.5, 0.6))
>>> cell_index(3.9, 0.75, 3), cell_index(-1.0, 0.75, 3), cell_index(float("nan"), 0.75, 3)
(2, 0, 0)
>>> cell_number(1, 2, 3, 4, 5), cell_coords(cell_number(1, 2, 3, 4, 5), 4, 5)
(69, (1, 2, 3))
>>> reach(4.0, False), reach(4.0, True), image_shift(4.0, False), image_shift(4.0, True)
(2.0, inf, 4.0, 8.0)
"""

import math

REAL = float
ZERO, ONE, TWO, INF = 0.0, 1.0, 2.0, math.inf

#: the functions of this module that the compiler builds, callees first
RULES = ("reach", "image_shift", "wrap", "minimum_image", "cell_index", "cell_number", "cell_coords", "fold",
         "push_out_2d", "push_out_3d")
#: the rules numba inlines into their callers (:func:`flocking.rules.compile` says which)
INLINED = ()


def reach(length, wall):
    """How far a displacement along an axis of side ``length`` reaches before the minimum
    image folds it (the ``half`` of :func:`minimum_image`): ``length / 2`` along a
    periodic axis, infinite across walls."""
    if wall:
        return INF
    return length / TWO


def image_shift(length, wall):
    """What a periodic image copied across the box's end along an axis is shifted by: the
    side ``length``, or across walls ``2 length``, which puts every wrapped copy out of
    reach of the particles inside."""
    if wall:
        return TWO * length
    return length


def wrap(x, length):
    """``x`` folded into ``[0, length)``; NaN and infinite coordinates (a broken state)
    are left as they are."""
    if not abs(x) < INF:
        return x
    x = x - length * REAL(math.floor(x / length))
    if x >= length:
        x -= length
    return x


def minimum_image(dx, length, half):
    """A displacement ``dx`` with ``|dx| < length`` folded into ``[-half, half]``: the
    nearest periodic image when ``half = length / 2``; unchanged when ``half = INF`` (an
    axis with walls)."""
    if dx > half:
        return dx - length
    if dx < -half:
        return dx + length
    return dx


def cell_index(x, inv, n):
    """The cell of coordinate ``x`` among ``n`` cells of width ``1 / inv``, always in
    ``[0, n)``: below 0 or NaN gives the first cell, beyond the box the last (a state
    read from a foreign file may hold anything; the step then stays in bounds)."""
    f = x * inv
    if f >= ONE:  # False for NaN
        if f >= REAL(n):
            return n - 1
        return int(f)
    return 0


def cell_number(c0, c1, c2, n0, n1):
    """The number of cell ``(c0, c1, c2)`` in a grid of ``n0 x n1 (x n2)`` cells: row by
    row, x fastest (a 2D grid has ``c2 = 0``). Every cell list of the package numbers its
    cells so."""
    return (c2 * n1 + c1) * n0 + c0


def cell_coords(c, n0, n1):
    """The cell ``(c0, c1, c2)`` numbered ``c`` by :func:`cell_number`."""
    return c % n0, (c // n0) % n1, c // (n0 * n1)


def fold(x, u, length, wall):
    """After a move, one coordinate and the heading's component along its axis: across a
    wall, reflected back into ``[0, length]`` with the component turned into the box;
    along a periodic axis, wrapped."""
    if wall:
        if x < ZERO:
            return -x, abs(u)
        if x > length:
            return TWO * length - x, -abs(u)
        return x, u
    return wrap(x, length), u


def push_out_2d(x, y, ux, uy, cx, cy, radius, l0, l1, h0, h1, w0, w1):
    """A particle at ``(x, y)`` with heading ``u`` inside the disc of ``radius`` around
    ``(cx, cy)`` (minimum image with half-lengths ``h``) is moved to its mirror point
    ``c + (2a - d) n`` across the surface (wrapped along periodic axes, ``w`` false),
    and its heading reflected if it points inward; one outside is left as it is. At the
    centre, ``n = -u``."""
    r0 = minimum_image(x - cx, l0, h0)
    r1 = minimum_image(y - cy, l1, h1)
    dist = math.sqrt(r0 * r0 + r1 * r1)
    if not dist < radius:
        return x, y, ux, uy
    if dist > ZERO:
        n0, n1 = r0 / dist, r1 / dist
    else:
        n0, n1 = -ux, -uy
    push = TWO * radius - dist
    x = cx + push * n0
    y = cy + push * n1
    if not w0:
        x = wrap(x, l0)
    if not w1:
        y = wrap(y, l1)
    dot = ux * n0 + uy * n1
    if dot < ZERO:
        ux = ux - TWO * dot * n0
        uy = uy - TWO * dot * n1
    return x, y, ux, uy


def push_out_3d(x, y, z, ux, uy, uz, cx, cy, cz, radius, l0, l1, l2, h0, h1, h2, w0, w1, w2):
    """:func:`push_out_2d` for a sphere."""
    r0 = minimum_image(x - cx, l0, h0)
    r1 = minimum_image(y - cy, l1, h1)
    r2 = minimum_image(z - cz, l2, h2)
    dist = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if not dist < radius:
        return x, y, z, ux, uy, uz
    if dist > ZERO:
        n0, n1, n2 = r0 / dist, r1 / dist, r2 / dist
    else:
        n0, n1, n2 = -ux, -uy, -uz
    push = TWO * radius - dist
    x = cx + push * n0
    y = cy + push * n1
    z = cz + push * n2
    if not w0:
        x = wrap(x, l0)
    if not w1:
        y = wrap(y, l1)
    if not w2:
        z = wrap(z, l2)
    dot = ux * n0 + uy * n1 + uz * n2
    if dot < ZERO:
        ux = ux - TWO * dot * n0
        uy = uy - TWO * dot * n1
        uz = uz - TWO * dot * n2
    return x, y, z, ux, uy, uz
