"""3D frames through a perspective camera: shaded cones along each heading, into RGB arrays.

Each particle is a solid cone whose tip points along its heading, ray-cast exactly
per pixel by a small numba kernel into a depth buffer (particles nearest the camera
first, so hidden ones cost a comparison), then lit like a studio render:

* a key light from the upper left, ambient light and a highlight on the cone's side;
* ambient occlusion read from the depth buffer: a pixel behind its neighbours is
  darkened, so clusters, holes and the outlines of single cones show;
* depth fog toward the background, and the box's wire frame hidden behind particles.

The picture is drawn at twice its size and averaged down (anti-aliasing). The colour of
a cone is its heading's (:func:`~flocking.viz.colors.heading_colors`), or any other
``(N, 3)`` colours passed in. Obstacles are shaded spheres in the same light, and the
edges of the box's wall faces are drawn thicker, in the text colour.

>>> from flocking.viz.colors import THEMES
>>> img = perspective_image(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), (4.0, 4.0, 4.0), 64,
...                         THEMES["dark"], length=2.0)
>>> img.shape, bool(img[30:34, 30:34].max() > 0.3)
((64, 64, 3), True)
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .colors import Theme, heading_colors

#: Cone length in units of the mean spacing ``(V / N)^(1/3)``, and its base radius / length.
LENGTH = 0.9
ASPECT = 0.3
#: Direction toward the key light in camera coordinates (x right, y up, z into the picture).
LIGHT = np.array([-0.45, 0.6, -0.66]) / np.linalg.norm([-0.45, 0.6, -0.66])


class Camera:
    """A perspective camera looking at the centre of a box from ``azim``/``elev`` degrees.

    Camera coordinates: ``x`` to the right of the picture, ``y`` up, ``z`` the depth
    (distance along the line of sight). The box's bounding sphere always fits the view;
    ``zoom`` below 1 leaves a margin around it (for labels).
    """

    def __init__(self, box_lengths, size: int, azim: float = -60.0, elev: float = 25.0, zoom: float = 1.0):
        self.size = int(size)
        lengths = np.asarray(box_lengths, dtype=float)
        self.diagonal = float(np.linalg.norm(lengths))
        self.distance = 2.2 * self.diagonal
        a, e = np.radians(azim), np.radians(elev)
        toward = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        self.eye = self.distance * toward
        self.forward = -toward
        right = np.cross(self.forward, [0.0, 0.0, 1.0])
        self.right = right / np.linalg.norm(right)
        self.up = np.cross(self.right, self.forward)
        half = 0.5 * self.diagonal
        self.focal = 0.5 * self.size * 1.02 * math.sqrt(self.distance**2 - half**2) / half * zoom
        self.near = self.distance - half
        self.far = self.distance + half

    @property
    def rotation(self) -> np.ndarray:
        """Rows: the world coordinates of the camera's x, y and z axes."""
        return np.stack([self.right, self.up, self.forward])

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` world points in camera coordinates."""
        return (np.asarray(points, float) - self.eye) @ self.rotation.T

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel column, pixel row (float, pixel centres at +0.5) and depth of each point."""
        c = self.to_camera(points)
        u = 0.5 * self.size + self.focal * c[:, 0] / c[:, 2]
        v = 0.5 * self.size - self.focal * c[:, 1] / c[:, 2]
        return u, v, c[:, 2]


def glyph_length(n: int, box_lengths, scale: float = 1.0) -> float:
    """Default cone length (world units): :data:`LENGTH` mean spacings, at most a tenth of
    the box's smallest side."""
    lengths = np.asarray(box_lengths, float)
    spacing = (float(np.prod(lengths)) / max(n, 1)) ** (1 / 3)
    return float(scale * min(LENGTH * spacing, 0.1 * lengths.min()))


@numba.njit(cache=True)
def _cones(centres, axes, albedo, length, radius, focal, size, light, depth, rgb):  # pragma: no cover
    """Ray-cast cones (tip at centre + length/2 axis) into ``depth`` and ``rgb``, nearest first."""
    half = 0.5 * length
    k = length * length / (length * length + radius * radius)  # cos^2 of the half-angle
    reach = math.sqrt(half * half + radius * radius)
    hx, hy, hz = 0.5 * (light[0] + 0.0), 0.5 * (light[1] + 0.0), 0.5 * (light[2] - 1.0)
    hn = math.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / hn, hy / hn, hz / hn  # Blinn's half vector for a viewer along -z
    centre = 0.5 * size
    for i in range(centres.shape[0]):
        cx, cy, cz = centres[i, 0], centres[i, 1], centres[i, 2]
        if cz - reach <= 1e-9:
            continue
        zmin = cz - reach
        ax_, ay, az = -axes[i, 0], -axes[i, 1], -axes[i, 2]  # from the tip toward the base
        tx, ty, tz = cx - half * ax_, cy - half * ay, cz - half * az  # tip
        bx, by, bz = cx + half * ax_, cy + half * ay, cz + half * az  # base centre
        # on screen the cone lies within the tip and the base's disc, widened by its radius
        ut, vt = centre + focal * tx / tz, centre - focal * ty / tz
        ub, vb = centre + focal * bx / bz, centre - focal * by / bz
        rb = focal * radius / max(bz - radius, 1e-9) + 1.0
        c0, c1 = max(int(min(ut - 1.0, ub - rb)), 0), min(int(max(ut + 1.0, ub + rb)) + 1, size)
        r0, r1 = max(int(min(vt - 1.0, vb - rb)), 0), min(int(max(vt + 1.0, vb + rb)) + 1, size)
        oa = -(tx * ax_ + ty * ay + tz * az)  # (origin - tip) . axis
        oo = tx * tx + ty * ty + tz * tz
        ba = bx * ax_ + by * ay + bz * az
        for row in range(r0, r1):
            dy = -(row + 0.5 - centre) / focal
            for col in range(c0, c1):
                if depth[row, col] <= zmin:
                    continue
                dx = (col + 0.5 - centre) / focal
                # the ray is t * (dx, dy, 1): t is the depth
                da = dx * ax_ + dy * ay + az
                dd = dx * dx + dy * dy + 1.0
                od = -(tx * dx + ty * dy + tz)
                best = np.inf
                nx = ny = nz = 0.0
                qa = da * da - k * dd
                qb = 2.0 * (da * oa - k * od)
                qc = oa * oa - k * oo
                disc = qb * qb - 4.0 * qa * qc
                if disc >= 0.0 and abs(qa) > 1e-12:
                    s = math.sqrt(disc)
                    for t in ((-qb - s) / (2.0 * qa), (-qb + s) / (2.0 * qa)):
                        if 0.0 < t < best:
                            wx, wy, wz = t * dx - tx, t * dy - ty, t - tz
                            h = wx * ax_ + wy * ay + wz * az
                            if 0.0 <= h <= length:
                                best = t
                                nx, ny, nz = k * wx - h * ax_, k * wy - h * ay, k * wz - h * az
                if abs(da) > 1e-12:
                    t = ba / da
                    if 0.0 < t < best:
                        ex, ey, ez = t * dx - bx, t * dy - by, t - bz
                        if ex * ex + ey * ey + ez * ez <= radius * radius:
                            best = t
                            nx, ny, nz = ax_, ay, az
                if best < depth[row, col]:
                    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                    nx, ny, nz = nx / norm, ny / norm, nz / norm
                    if nx * dx + ny * dy + nz > 0.0:  # seen from inside: face the viewer
                        nx, ny, nz = -nx, -ny, -nz
                    diffuse = max(nx * light[0] + ny * light[1] + nz * light[2], 0.0)
                    spec = max(nx * hx + ny * hy + nz * hz, 0.0) ** 40
                    shade = 0.52 + 0.62 * diffuse
                    depth[row, col] = best
                    for c in range(3):
                        rgb[row, col, c] = albedo[i, c] * shade + 0.3 * spec


@numba.njit(cache=True)
def _hidden(depth, kind, y, x, r, scale):  # pragma: no cover
    """How hidden pixel (y, x) is among the surfaces ``r`` pixels around it: the mean over 8
    neighbours of how much nearer each is, in units of ``scale``, each counted up to 1."""
    rows, cols = depth.shape
    d = depth[y, x]
    total = 0.0
    for dy in (-r, 0, r):
        for dx in (-r, 0, r):
            yy, xx = y + dy, x + dx
            if (dy == 0 and dx == 0) or yy < 0 or yy >= rows or xx < 0 or xx >= cols or kind[yy, xx] != 1:
                continue
            total += min(max((d - depth[yy, xx]) / scale, 0.0), 1.0)
    return total / 8.0


@numba.njit(cache=True)
def _compose(depth, kind, rgb, ss, wide, scale, near, far, background, out):  # pragma: no cover
    """Ambient occlusion (near and ``wide`` neighbours), depth fog, background, and the
    average of each ``ss x ss`` block into ``out``."""
    size = out.shape[0]
    for oy in range(size):
        for ox in range(size):
            acc0 = acc1 = acc2 = 0.0
            for sy in range(ss):
                for sx in range(ss):
                    y, x = oy * ss + sy, ox * ss + sx
                    k = kind[y, x]
                    if k == 0:
                        r, g, b = background[0], background[1], background[2]
                    else:
                        light = 1.0
                        if k == 1:
                            occ = 0.35 * _hidden(depth, kind, y, x, wide, scale) \
                                + 0.3 * _hidden(depth, kind, y, x, ss, 0.5 * scale)
                            light = 1.0 - min(occ, 0.8)
                        fog = 0.5 * min(max((depth[y, x] - near) / (far - near), 0.0), 1.0)
                        r = rgb[y, x, 0] * light * (1 - fog) + background[0] * fog
                        g = rgb[y, x, 1] * light * (1 - fog) + background[1] * fog
                        b = rgb[y, x, 2] * light * (1 - fog) + background[2] * fog
                    acc0 += min(max(r, 0.0), 1.0)
                    acc1 += min(max(g, 0.0), 1.0)
                    acc2 += min(max(b, 0.0), 1.0)
            n = ss * ss
            out[oy, ox, 0] = acc0 / n
            out[oy, ox, 1] = acc1 / n
            out[oy, ox, 2] = acc2 / n


def _box_edges(lengths: np.ndarray, samples: int, walls=(False, False, False)) -> tuple[np.ndarray, np.ndarray]:
    """Points along the box's 12 edges, and whether each lies on a wall face (an edge
    along axis a lies on the faces across the other two axes)."""
    half = 0.5 * lengths
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    t = np.linspace(0.0, 1.0, samples)[:, None]
    points, on_wall = [], []
    for i in range(8):
        for j in range(i + 1, 8):
            if np.count_nonzero(corners[i] != corners[j]) == 1:
                along = int(np.flatnonzero(corners[i] != corners[j])[0])
                points.append(corners[i] + t * (corners[j] - corners[i]))
                on_wall.append(np.full(samples, any(w for a, w in enumerate(walls) if a != along)))
    return np.concatenate(points), np.concatenate(on_wall)


def _spheres(cam: Camera, spheres: np.ndarray, albedo, lengths, depth: np.ndarray, rgb: np.ndarray) -> None:
    """Ray-cast spheres (rows: centre, radius; world coordinates) cut by the box (a copy
    across a periodic side shows its flat cut) into ``depth`` and ``rgb``, lit like the cones."""
    size = cam.size
    centre = 0.5 * size
    half = 0.5 * (LIGHT + np.array([0.0, 0.0, -1.0]))
    half /= np.linalg.norm(half)
    box_centre = cam.to_camera(np.zeros((1, 3)))[0]
    for row in np.asarray(spheres, float).reshape(-1, 4):
        c, r = cam.to_camera(row[None, :3])[0], row[3]
        if c[2] - r <= 1e-9:
            continue
        u, v = centre + cam.focal * c[0] / c[2], centre - cam.focal * c[1] / c[2]
        reach = cam.focal * r / (c[2] - r) + 2.0
        c0, c1 = max(int(u - reach), 0), min(int(u + reach) + 1, size)
        r0, r1 = max(int(v - reach), 0), min(int(v + reach) + 1, size)
        if c0 >= c1 or r0 >= r1:
            continue
        dx = np.broadcast_to(((np.arange(c0, c1) + 0.5 - centre) / cam.focal)[None, :], (r1 - r0, c1 - c0))
        dy = np.broadcast_to((-(np.arange(r0, r1) + 0.5 - centre) / cam.focal)[:, None], (r1 - r0, c1 - c0))
        ray = np.stack([dx, dy, np.ones_like(dx)], axis=-1)  # the ray is t * ray: t is the depth
        dd = np.einsum("...i,...i", ray, ray)
        dc = ray @ c
        disc = np.maximum(dc * dc - dd * (c @ c - r * r), 0.0)
        inside_ray = dc * dc - dd * (c @ c - r * r) >= 0
        t_in, t_out = (dc - np.sqrt(disc)) / dd, (dc + np.sqrt(disc)) / dd
        # the box's slabs, in camera coordinates: the ray is in the box for t in [enter, leave]
        enter, leave = np.zeros_like(dd), np.full_like(dd, np.inf)
        face = np.full(dd.shape, -1)
        for axis, length in enumerate(lengths):
            n = cam.rotation[:, axis]  # the world axis in camera coordinates
            along, at = ray @ n, box_centre @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t0, t1 = (at - length / 2) / along, (at + length / 2) / along
            near, far = np.minimum(t0, t1), np.maximum(t0, t1)
            near = np.where(along == 0, -np.inf, near)
            far = np.where(along == 0, np.inf, far)
            face = np.where(near > enter, axis, face)
            enter, leave = np.maximum(enter, near), np.minimum(leave, far)
        t = np.maximum(t_in, enter)
        hit = inside_ray & (t <= np.minimum(t_out, leave)) & (t > 0) & (t < depth[r0:r1, c0:c1])
        if not hit.any():
            continue
        t = np.where(hit, t, c[2])  # misses: any finite depth, their colour is not used
        normal = (t[..., None] * ray - c) / r
        cut = hit & (enter > t_in)  # the ray enters the sphere outside the box: the flat cut
        for axis in range(len(lengths)):
            n = cam.rotation[:, axis]
            toward = -np.sign(ray @ n)[..., None] * n  # the face's normal toward the camera
            normal = np.where((cut & (face == axis))[..., None], toward, normal)
        diffuse = np.maximum(normal @ LIGHT, 0.0)
        spec = np.maximum(normal @ half, 0.0) ** 40
        colour = np.asarray(albedo, float)[None, None, :] * (0.52 + 0.62 * diffuse)[..., None] + 0.3 * spec[..., None]
        depth[r0:r1, c0:c1][hit] = t[hit]
        rgb[r0:r1, c0:c1][hit] = colour[hit]


def perspective_image(points: np.ndarray, headings: np.ndarray, box_lengths, size: int,
                      theme: Theme, azim: float = -60.0, elev: float = 25.0,
                      length: float | None = None, colors: np.ndarray | None = None,
                      supersample: int = 2, walls=(False, False, False), obstacles=None,
                      zoom: float = 1.0) -> np.ndarray:
    """``size x size`` RGB image of a 3D frame (points centred in the box).

    ``length`` is the cone length in world units (default :func:`glyph_length`);
    ``colors`` are ``(N, 3)`` RGB albedos (default: by heading); ``walls`` (per axis)
    mark the edges of wall faces; ``obstacles`` are spheres (rows: centre, radius);
    ``zoom`` as :class:`Camera`'s.
    """
    ss = max(1, int(supersample))
    big = int(size) * ss
    lengths = np.asarray(box_lengths, dtype=float)
    cam = Camera(lengths, big, azim, elev, zoom)
    points = np.asarray(points, float).reshape(-1, 3)
    headings = np.asarray(headings, float).reshape(-1, 3)
    n = len(points)
    length = glyph_length(n, lengths) if length is None else float(length)
    depth = np.full((big, big), np.inf)
    rgb = np.zeros((big, big, 3))
    if n:
        albedo = heading_colors(headings, theme) if colors is None else np.asarray(colors, float)
        centres = cam.to_camera(points)
        axes = headings @ cam.rotation.T
        order = np.argsort(centres[:, 2], kind="stable")  # nearest first
        _cones(np.ascontiguousarray(centres[order]), np.ascontiguousarray(axes[order]),
               np.ascontiguousarray(albedo[order]), length, ASPECT * length, cam.focal, big, LIGHT,
               depth, rgb)
    if obstacles is not None and len(obstacles):
        albedo = 0.65 * np.asarray(theme.obstacle) + 0.35  # lighter than the discs of 2D: shading darkens
        _spheres(cam, obstacles, albedo, lengths, depth, rgb)
    kind = np.isfinite(depth).astype(np.uint8)  # 0 background, 1 a cone or sphere, 2 the wire frame
    # the box's wire frame, hidden where a particle is in front of it; wall edges thicker
    edges, on_wall = _box_edges(lengths, 3 * big, walls)
    u, v, z = cam.project(edges)
    thin = [(0, 0)] + ([(1, 0), (0, 1), (1, 1)] if ss > 1 else [])
    thick = [(du, dv) for du in range(-ss, ss + 1) for dv in range(-ss, ss + 1)]
    for du, dv in thick:
        drawn = on_wall | ((du, dv) in thin)
        iu, iv = np.floor(u).astype(np.int64) + du, np.floor(v).astype(np.int64) + dv
        ok = drawn & (iu >= 0) & (iu < big) & (iv >= 0) & (iv < big)
        ok[ok] &= depth[iv[ok], iu[ok]] > z[ok]
        rgb[iv[ok], iu[ok]] = np.where(on_wall[ok, None], theme.text, theme.edge)
        depth[iv[ok], iu[ok]] = z[ok]
        kind[iv[ok], iu[ok]] = 2
    image = np.empty((int(size), int(size), 3))
    wide = max(1, int(round(1.5 * cam.focal * length / cam.distance)))  # a cone's length on screen
    _compose(depth, kind, rgb, ss, wide, length, cam.near, cam.far, np.asarray(theme.background, float), image)
    return image
