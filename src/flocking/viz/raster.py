"""Frames drawn straight into RGB arrays with NumPy: fast at any particle count.

* :func:`density_image` (2D): a histogram of counts and of summed heading vectors; the
  hue of a pixel is the local mean heading, its brightness the local density and its
  saturation the local order, so a band of a million particles reads at a glance.
* :func:`perspective_image` (3D): particles as depth-cued discs with a short tail along
  their heading, seen through a perspective camera, inside the box's wire frame.

Both return ``float`` RGB arrays in [0, 1], rows top to bottom (image order).

>>> from flocking.viz.colors import THEMES
>>> pos = np.array([[0.5, 0.5]]); head = np.array([[1.0, 0.0]])
>>> img = density_image(pos, head, (4.0, 4.0), (4, 4), THEMES["dark"], blur=False)
>>> img.shape, img[1, 2].round(2).tolist()          # row 1 from the top: y in (0, 1]
((4, 4, 3), [1.0, 0.0, 0.0])
"""

from __future__ import annotations

import numpy as np

from .colors import Theme, heading_colors, hsv_to_rgb


def density_bins(n: int, box_lengths, max_pixels: int) -> tuple[int, int]:
    """``(rows, columns)`` of the density grid: about 3 particles a bin, at most the pixels."""
    lx, ly = float(box_lengths[0]), float(box_lengths[1])
    cells = max(1.0, n / 3.0)
    nx = int(np.sqrt(cells * lx / ly))
    nx = max(8, min(max_pixels, nx))
    ny = max(8, min(max_pixels, int(round(nx * ly / lx))))
    return ny, nx


def _blur(a: np.ndarray) -> np.ndarray:
    """Periodic [1, 2, 1] / 4 blur along both axes (the box is periodic)."""
    for axis in (0, 1):
        a = 0.5 * a + 0.25 * (np.roll(a, 1, axis) + np.roll(a, -1, axis))
    return a


def density_image(positions: np.ndarray, headings: np.ndarray, box_lengths, shape,
                  theme: Theme, blur: bool = True) -> np.ndarray:
    """``shape = (rows, columns)`` RGB image of a 2D frame (positions centred in the box)."""
    ny, nx = shape
    lx, ly = float(box_lengths[0]), float(box_lengths[1])
    ix = np.clip(((positions[:, 0] / lx + 0.5) * nx).astype(np.int64), 0, nx - 1)
    iy = np.clip(((0.5 - positions[:, 1] / ly) * ny).astype(np.int64), 0, ny - 1)  # rows downward
    cell = iy * nx + ix
    size = nx * ny
    count = np.bincount(cell, minlength=size).astype(float).reshape(ny, nx)
    sx = np.bincount(cell, weights=headings[:, 0], minlength=size).reshape(ny, nx)
    sy = np.bincount(cell, weights=headings[:, 1], minlength=size).reshape(ny, nx)
    if blur:
        count, sx, sy = _blur(count), _blur(sx), _blur(sy)
    occupied = count[count > 0]
    ref = np.percentile(occupied, 99.0) if occupied.size else 1.0
    value = np.clip(count / max(ref, 1e-12), 0.0, 1.0) ** 0.6
    order = np.divide(np.hypot(sx, sy), count, out=np.zeros_like(count), where=count > 0)
    hue = np.arctan2(sy, sx) / (2 * np.pi)
    color = hsv_to_rgb(hue, 0.3 + 0.7 * np.sqrt(np.clip(order, 0, 1)), theme.value)
    alpha = value[..., None]
    return alpha * color + (1 - alpha) * np.asarray(theme.background)


class Camera:
    """A perspective camera on a box centred at the origin, from ``azim``/``elev`` degrees."""

    def __init__(self, box_lengths, size: int, azim: float = -60.0, elev: float = 25.0):
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
        self.focal = 0.5 * self.size * 1.1 * (self.distance - half) / half  # a cube never leaves the view

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel column, pixel row (float) and depth of each point."""
        rel = points - self.eye
        depth = rel @ self.forward
        u = self.focal * (rel @ self.right) / depth + 0.5 * self.size
        v = 0.5 * self.size - self.focal * (rel @ self.up) / depth
        return u, v, depth

    def shade(self, depth: np.ndarray) -> np.ndarray:
        """Depth cue: 1 at the nearest corner of the box, 0.35 at the farthest."""
        near = self.distance - 0.5 * self.diagonal
        return 1.0 - 0.65 * np.clip((depth - near) / self.diagonal, 0.0, 1.0)


def _disc(radius: float) -> list[tuple[int, int]]:
    r = max(radius, 0.5)
    span = int(np.ceil(r))
    return [(dx, dy) for dy in range(-span, span + 1) for dx in range(-span, span + 1)
            if dx * dx + dy * dy <= r * r + 0.25]


def _stamp(flat: np.ndarray, size: int, u, v, colors, offsets) -> None:
    """Paint each point's offsets; later points win (callers sort far to near)."""
    iu, iv = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    for dx, dy in offsets:
        x, y = iu + dx, iv + dy
        ok = (x >= 0) & (x < size) & (y >= 0) & (y < size)
        flat[y[ok] * size + x[ok]] = colors[ok]


def _box_edges(lengths: np.ndarray, samples: int) -> np.ndarray:
    half = 0.5 * lengths
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    t = np.linspace(0.0, 1.0, samples)[:, None]
    edges = [corners[i] + t * (corners[j] - corners[i]) for i in range(8) for j in range(i + 1, 8)
             if np.count_nonzero(corners[i] != corners[j]) == 1]
    return np.concatenate(edges)


def perspective_image(points: np.ndarray, headings: np.ndarray, box_lengths, size: int,
                      theme: Theme, azim: float = -60.0, elev: float = 25.0,
                      radius: float | None = None, tail: float = 1.0,
                      supersample: int = 2) -> np.ndarray:
    """``size x size`` RGB image of a 3D frame; ``radius`` in pixels (default from N)."""
    ss = int(supersample)
    big = size * ss
    lengths = np.asarray(box_lengths, dtype=float)
    cam = Camera(lengths, big, azim, elev)
    flat = np.empty((big * big, 3))
    flat[:] = theme.background
    # wire frame first: particles in front of a far edge hide it
    edges = _box_edges(lengths, 2 * big)
    eu, ev, ed = cam.project(edges)
    edge_rgb = np.asarray(theme.edge) * cam.shade(ed)[:, None] + np.asarray(theme.background) * (1 - cam.shade(ed)[:, None])
    _stamp(flat, big, eu, ev, edge_rgb, _disc(0.5 * ss))
    n = len(points)
    if n:
        if radius is None:
            spacing = 0.55 * size / max(n, 1) ** (1 / 3)
            radius = float(np.clip(0.14 * spacing, 0.5, 4.0))
        order = np.argsort(-(points @ cam.forward), kind="stable")   # far to near
        pts, heads = points[order].astype(float), headings[order]
        u, v, depth = cam.project(pts)
        shade = cam.shade(depth)[:, None]
        base = heading_colors(heads, theme)
        bg = np.asarray(theme.background)
        rgb = base * shade + bg * (1 - shade)
        tail_rgb = base * (0.55 * shade) + bg * (1 - 0.55 * shade)
        # tail: a thin line behind each particle, about 3 radii long on screen
        tail_world = tail * 3.0 * radius * ss * depth / cam.focal
        tu, tv, _ = cam.project(pts - heads * tail_world[:, None])
        head_disc = _disc(radius * ss)
        thin = _disc(0.5 * ss)
        steps = max(2, int(3 * radius))
        slabs = np.array_split(np.arange(n), min(8, n))
        for slab in slabs:
            for k in range(1, steps + 1):
                f = k / steps
                _stamp(flat, big, u[slab] + f * (tu[slab] - u[slab]), v[slab] + f * (tv[slab] - v[slab]),
                       tail_rgb[slab], thin)
            _stamp(flat, big, u[slab], v[slab], rgb[slab], head_disc)
    image = flat.reshape(big, big, 3)
    if ss > 1:
        image = image.reshape(size, ss, size, ss, 3).mean(axis=(1, 3))
    return image
