"""Voronoi neighbours for the reference backend, by brute force: each particle's Voronoi
cell built from its definition, independently of any triangulation.

The cell of a site ``p`` is the set of points at least as near to ``p`` as to every other
point of the infinite set of images (shifted by whole box sides along periodic axes,
mirrored across the walls along walled ones, so that a cell ends at a wall): the
intersection of the half-spaces ``(q - p) . x <= (|q|^2 - |p|^2) / 2``. Its vertices are
found by brute force: every ``d`` of the bounding planes of the ``m`` nearest points (and a
cube around ``p``) meet in a point, kept if it satisfies every inequality. The cell is
exact once no vertex lies on the cube and every point left out is farther than ``2 rho``
from ``p``, ``rho`` the largest distance of a vertex (beyond it no bisector can cut the
cell); else ``m`` (and the images) grow. ``q`` is a neighbour when its plane holds a side
of positive length (2D: two vertices farther apart than ``TIE`` mean spacings) or a face
of positive area (3D: three vertices making a triangle of area above ``TIE`` times the squared spacing).

Coincident particles are one site: neighbours of each other, sharing the site's
neighbours. A particle is never its own neighbour. The same rules as the CPU backend's
(:mod:`flocking.backends.delaunay`), found another way.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

#: see the module's docstring (the same value as the CPU backend's)
TIE = 1e-9


def image_set(sites: np.ndarray, box: np.ndarray, walls: np.ndarray, reach: int) -> tuple[np.ndarray, np.ndarray]:
    """Every image of the sites within ``reach`` box sides of the box: ``(points, source)``."""
    d = sites.shape[1]
    per_axis = []
    for a in range(d):
        if walls[a]:
            per_axis.append([(s, 2 * k * box[a]) for k in range(-reach, reach + 1) for s in (1.0, -1.0)])
        else:
            per_axis.append([(1.0, k * box[a]) for k in range(-reach, reach + 1)])
    pts, src = [], []
    for maps in itertools.product(*per_axis):
        moved = sites.copy()
        for a, (sign, shift) in enumerate(maps):
            moved[:, a] = sign * sites[:, a] + shift
        pts.append(moved)
        src.append(np.arange(len(sites)))
    return np.concatenate(pts), np.concatenate(src)


def cell_vertices(p: np.ndarray, normals: np.ndarray, offsets: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of ``{x : normals . x <= offsets}`` (normals of unit length) by brute
    force, and for each plane which vertices lie on it (``(planes, vertices)`` booleans)."""
    d = len(p)
    combos = np.array(list(itertools.combinations(range(len(normals)), d)))
    a = normals[combos]
    b = offsets[combos]
    det = np.linalg.det(a)
    ok = np.abs(det) > 1e-12
    a, b = a[ok], b[ok]
    x = np.linalg.solve(a, b[..., None])[..., 0]
    slack = normals @ x.T - offsets[:, None]
    inside = np.all(slack <= tol, axis=0)
    x = x[inside]
    return x, np.abs(slack[:, inside]) <= tol


def facet_measure(vertices: np.ndarray) -> float:
    """Length (2D) or largest triangle area (3D) spanned by the vertices on one plane."""
    if len(vertices) < vertices.shape[1]:
        return 0.0
    e = vertices[1:] - vertices[0]
    if vertices.shape[1] == 2:
        return float(np.max(np.sqrt(np.sum(e * e, axis=1))))
    best = 0.0
    for u in range(len(e)):
        c = np.cross(e[u], e[u + 1:])
        if len(c):
            best = max(best, 0.5 * float(np.max(np.sqrt(np.sum(c * c, axis=1)))))
    return best


def site_neighbours(k: int, sites: np.ndarray, box: np.ndarray, walls: np.ndarray, spacing: float) -> set[int]:
    """The sites whose cells share a side (face) of positive measure with site ``k``'s."""
    d = sites.shape[1]
    p = sites[k]
    tol = 1e-10 * spacing
    m, reach = 4 * d * d, 1
    while True:
        pts, src = image_set(sites, box, walls, reach)
        r = pts - p
        dist = np.sqrt(np.sum(r * r, axis=1))
        others = np.flatnonzero(dist > 0)
        others = others[np.argsort(dist[others], kind="stable")]
        near = others[:m]
        limit = dist[others[m]] if len(others) > m else reach * float(np.min(box))
        normals = r[near] / dist[near, None]
        offsets = normals @ p + dist[near] / 2
        cube = np.concatenate([np.eye(d), -np.eye(d)])
        normals = np.concatenate([normals, cube])
        offsets = np.concatenate([offsets, cube @ p + limit])
        x, on = cell_vertices(p, normals, offsets, tol)
        rho = float(np.max(np.sqrt(np.sum((x - p) ** 2, axis=1))))
        exact = 2 * rho <= limit and not on[len(near):].any()
        if exact:
            break
        if len(others) > m:
            m *= 2
        else:
            reach += 1
    out = set()
    size = TIE * spacing ** (d - 1)
    for row, q in enumerate(near):
        if src[q] != k and facet_measure(x[on[row]]) > size:
            out.add(int(src[q]))
    return out


def voronoi_matrix(positions: np.ndarray, box, walls) -> np.ndarray:
    """``A[i, j]`` is True when ``j != i`` is a Voronoi neighbour of ``i`` (positions ``(n, d)``)."""
    n, d = positions.shape
    box, walls = np.asarray(box, dtype=np.float64), np.asarray(walls, dtype=bool)
    a = np.zeros((n, n), dtype=bool)
    if n < 2:
        return a
    sites, site_of = np.unique(positions, axis=0, return_inverse=True)
    site_of = site_of.reshape(-1)
    spacing = (math.prod(box) / len(sites)) ** (1.0 / d)
    near = np.zeros((len(sites), len(sites)), dtype=bool)
    if len(sites) > 1:
        for k in range(len(sites)):
            for q in site_neighbours(k, sites, box, walls, spacing):
                near[k, q] = True
    np.fill_diagonal(near, True)  # coincident particles are neighbours of each other
    a = near[site_of[:, None], site_of[None, :]]
    np.fill_diagonal(a, False)
    return a
