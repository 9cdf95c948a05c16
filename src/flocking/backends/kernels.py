"""Per-particle arithmetic of one step, compiled by numba and shared by the CPU kernels.

Each function takes and returns scalars (no allocation in the hot loop) and implements
exactly the formulas of :mod:`flocking.backends.reference`, in the same order of
floating-point operations where that matters, so a step of the fast backend matches a
reference step to rounding.
"""

import math

import numba

from .. import rng

_jit = numba.njit(cache=True, inline="always", fastmath=False, error_model="numpy")


@_jit
def minimum_image(dx, length, half):
    if dx > half:
        return dx - length
    if dx < -half:
        return dx + length
    return dx


@_jit
def wrap(x, length):
    x = x - length * math.floor(x / length)
    if x >= length:
        x -= length
    return x


@_jit
def update_2d(ux, uy, sx, sy, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, turn):
    """From ``u_i(t)``, the sum ``S_i`` and its number of terms to ``u_i(t+1)`` (2D):
    field ``h g``, noise ``eta``, alignment ``epsilon``, chirality ``turn = omega dt``."""
    z0 = rng.uniform_jit(seed, step, pid, rng.NOISE)
    if h != 0.0:
        sx = sx + h * count * gx
        sy = sy + h * count * gy
    if vectorial:
        angle = 2.0 * math.pi * z0
        sx = sx + eta * count * math.cos(angle)
        sy = sy + eta * count * math.sin(angle)
    norm = math.sqrt(sx * sx + sy * sy)
    if norm > 0.0:
        mx, my = sx / norm, sy / norm
    else:
        mx, my = ux, uy
    if epsilon == 1.0:
        wx, wy = mx, my
    else:
        a = epsilon * math.atan2(ux * my - uy * mx, ux * mx + uy * my)
        c, s = math.cos(a), math.sin(a)
        wx, wy = ux * c - uy * s, ux * s + uy * c
    if turn != 0.0:
        c, s = math.cos(turn), math.sin(turn)
        wx, wy = wx * c - wy * s, wx * s + wy * c
    if not vectorial:
        a = eta * (z0 - 0.5)
        c, s = math.cos(a), math.sin(a)
        wx, wy = wx * c - wy * s, wx * s + wy * c
    norm = math.sqrt(wx * wx + wy * wy)
    return wx / norm, wy / norm


@_jit
def update_3d(ux, uy, uz, sx, sy, sz, count, epsilon, eta, vectorial, seed, step, pid, h, gx, gy, gz):
    """From ``u_i(t)``, the sum ``S_i`` and its number of terms to ``u_i(t+1)`` (3D),
    with the field ``h g``."""
    z0 = rng.uniform_jit(seed, step, pid, rng.NOISE)
    z1 = rng.uniform_jit(seed, step, pid, rng.NOISE + 1)
    if h != 0.0:
        sx = sx + h * count * gx
        sy = sy + h * count * gy
        sz = sz + h * count * gz
    if vectorial:
        z = 2.0 * z0 - 1.0
        rho = math.sqrt(max(0.0, 1.0 - z * z))
        angle = 2.0 * math.pi * z1
        sx = sx + eta * count * (rho * math.cos(angle))
        sy = sy + eta * count * (rho * math.sin(angle))
        sz = sz + eta * count * z
    norm = math.sqrt(sx * sx + sy * sy + sz * sz)
    if norm > 0.0:
        mx, my, mz = sx / norm, sy / norm, sz / norm
    else:
        mx, my, mz = ux, uy, uz
    if epsilon == 1.0:
        wx, wy, wz = mx, my, mz
    else:
        c = ux * mx + uy * my + uz * mz
        cx, cy, cz = uy * mz - uz * my, uz * mx - ux * mz, ux * my - uy * mx
        s = math.sqrt(cx * cx + cy * cy + cz * cz)
        if s < 1e-12:
            if c > 0:
                wx, wy, wz = mx, my, mz
            else:
                wx, wy, wz = ux, uy, uz
        else:
            alpha = math.atan2(s, c)
            f, g = math.sin((1.0 - epsilon) * alpha), math.sin(epsilon * alpha)
            wx, wy, wz = (f * ux + g * mx) / s, (f * uy + g * my) / s, (f * uz + g * mz) / s
    if not vectorial:
        cos_b = 1.0 - z0 * (2.0 * math.sin(eta / 4.0) ** 2)
        sin_b = math.sqrt(max(0.0, 1.0 - cos_b * cos_b))
        phi = 2.0 * math.pi * z1
        if abs(wx) < 0.9:
            ax, ay = 1.0, 0.0
        else:
            ax, ay = 0.0, 1.0
        dot = ax * wx + ay * wy
        e1x, e1y, e1z = ax - dot * wx, ay - dot * wy, 0.0 - dot * wz
        n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
        e2x, e2y, e2z = wy * e1z - wz * e1y, wz * e1x - wx * e1z, wx * e1y - wy * e1x
        cp, sp = math.cos(phi), math.sin(phi)
        wx = cos_b * wx + sin_b * (cp * e1x + sp * e2x)
        wy = cos_b * wy + sin_b * (cp * e1y + sp * e2y)
        wz = cos_b * wz + sin_b * (cp * e1z + sp * e2z)
    norm = math.sqrt(wx * wx + wy * wy + wz * wz)
    return wx / norm, wy / norm, wz / norm
