"""Voronoi neighbours for the CPU backend: Qhull's Delaunay triangulation of the particles
and of their images near the box's sides, a margin proved wide enough, ties resolved.

Two particles are Voronoi neighbours when their Voronoi cells share a side (3D: a face) of
positive length (area). :func:`graph` finds them for particles in the box ``[0, L)^d``:

Images. Along a periodic axis, a particle's images are it shifted by whole box sides; along
an axis closed by walls, its mirror images across the walls (``-x``, ``2L - x``, and
beyond). For a point inside the box no image across a wall is nearer than the particle
itself, so the cell of a particle among all images is its own cell clipped by the walls:
no neighbour across a wall, and no cell without bounds.

Margin. Qhull triangulates the particles and their images within ``w`` of the box
(``[-w, L + w]`` along every axis). A simplex whose circumsphere lies within that region is
a Delaunay simplex of the infinite set of images too: every image inside the sphere is in
the triangulated set, which has none inside. If every simplex touching a particle in the
box passes that test, the simplices around each particle are the true ones, and so are its
neighbours. :func:`graph` starts from ``w = 4`` mean spacings (random states need about 3.4) and, while a simplex fails,
triangulates again with the margin its sphere needs (plus a tenth): exact, not a guess.
Flat simplices (zero volume: Qhull's triangulation of points on one circle or sphere in
3D) have no circumsphere and are left out of the test and of the ties below; their points
are also vertices of the simplices around them.

Ties (a lattice, points on a circle). Qhull triangulates four co-circular points with one
diagonal or the other; its two triangles have one circumcircle, so the diagonal's Voronoi
side has no length. A Delaunay edge is kept when the circumcentres of the simplices
around it span a side of positive length (2D: two centres farther apart than ``TIE`` mean
spacings) or a face of positive area (3D: three centres making a triangle of area above
``TIE`` times the squared spacing): a square lattice has 4 neighbours, a cubic one 6, whichever
diagonals Qhull draws.

Coincident particles (the same coordinates exactly) are one site: they are neighbours of
each other and share the site's neighbours. A particle Qhull leaves out (within its
rounding of another point) takes the place of the nearest vertex it names, the same way.
A particle is never its own neighbour (its images are not neighbours). If Qhull cannot
triangulate at all (every site and image on one line or plane, possible only with walls
and a few particles), every particle is a neighbour of every other.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..checks import ParameterError

#: a Voronoi side shorter than this many mean spacings (3D: a face of area under this times
#: the squared spacing) is a tie and not a side: see the module's docstring
TIE = 1e-9

#: the first margin, in mean spacings, and how many times a margin may grow
FIRST_MARGIN = 4.0
TRIES = 12


def qhull():
    """scipy's Delaunay, or a one-line error saying how to get it."""
    try:
        from scipy.spatial import Delaunay, QhullError
    except ImportError:
        raise ParameterError("neighbours: 'voronoi' on the cpu backend needs scipy "
                             "(pip install 'flocking[voronoi]')") from None
    return Delaunay, QhullError


def images(sites: np.ndarray, box: np.ndarray, walls: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray]:
    """The sites ``(u, d)`` first, then their images within ``w`` of the box along every
    axis (shifts along periodic axes, mirror images along walled ones): ``(points,
    source)``, ``source`` the site behind each point."""
    pts, src = sites, np.arange(len(sites))
    for a in range(sites.shape[1]):
        length = box[a]
        reach = int(math.ceil(w / length)) + 1
        extra_p, extra_s = [], []
        for k in range(-reach, reach + 1):
            maps = [(1.0, k * length)] if not walls[a] else [(1.0, 2 * k * length), (-1.0, 2 * k * length)]
            for sign, shift in maps:
                if sign == 1.0 and shift == 0.0:
                    continue
                x = sign * pts[:, a] + shift
                keep = (x >= -w) & (x <= length + w)
                if walls[a]:
                    keep &= x != pts[:, a]  # a site on the wall is its own mirror image
                moved = pts[keep].copy()
                moved[:, a] = x[keep]
                extra_p.append(moved)
                extra_s.append(src[keep])
        pts = np.concatenate([pts, *extra_p])
        src = np.concatenate([src, *extra_s])
    return pts, src


def circumspheres(points: np.ndarray, simplices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Circumcentres ``(s, d)``, squared radii and whether each simplex is flat (no sphere)."""
    v = points[simplices]
    e = v[:, 1:] - v[:, :1]
    rhs = 0.5 * np.sum(e * e, axis=2)
    det = np.linalg.det(e)
    scale = np.prod(np.sqrt(np.sum(e * e, axis=2)), axis=1)
    flat = ~(np.abs(det) > 1e-12 * scale)
    e[flat] = np.eye(points.shape[1])
    c = np.linalg.solve(e, rhs[..., None])[..., 0]
    c[flat] = 0.0
    return v[:, 0] + c, np.sum(c * c, axis=1), flat


def margin_needed(centre, r2, box):
    """How far beyond the box each sphere reaches along its worst axis."""
    r = np.sqrt(r2)[:, None]
    return np.max(np.maximum(r - centre, centre + r - box[None, :]), axis=1)


@numba.njit(cache=True)
def sides(simplices, flat, centres, n_sites, tol):
    """The Delaunay edges ``(a, b)`` (point indices, ``a < b``, at least one a site) whose
    Voronoi side has positive measure by :data:`TIE`: the circumcentres of the non-flat
    simplices around the edge span a segment longer than ``tol`` (2D) or a triangle of
    area above ``tol`` (3D, ``tol`` an area)."""
    s, m = simplices.shape
    d = m - 1
    keys = np.empty(s * m * (m - 1) // 2, dtype=np.int64)
    owner = np.empty(keys.shape[0], dtype=np.int64)
    big = np.int64(simplices.max() + 1)
    q = 0
    for t in range(s):
        if flat[t]:
            continue
        for u in range(m):
            for v in range(u + 1, m):
                a, b = simplices[t, u], simplices[t, v]
                if a > b:
                    a, b = b, a
                if a < n_sites:
                    keys[q] = a * big + b
                    owner[q] = t
                    q += 1
    order = np.argsort(keys[:q], kind="mergesort")
    out = np.empty((q, 2), dtype=np.int64)
    e = 0
    g = 0
    while g < q:
        h = g
        key = keys[order[g]]
        while h < q and keys[order[h]] == key:
            h += 1
        c0 = centres[owner[order[g]]]
        best = 0.0
        for p in range(g + 1, h):
            cp = centres[owner[order[p]]] - c0
            if d == 2:
                best = max(best, math.sqrt(cp[0] * cp[0] + cp[1] * cp[1]))
            else:
                for r in range(p + 1, h):
                    cr = centres[owner[order[r]]] - c0
                    x = cp[1] * cr[2] - cp[2] * cr[1]
                    y = cp[2] * cr[0] - cp[0] * cr[2]
                    z = cp[0] * cr[1] - cp[1] * cr[0]
                    best = max(best, 0.5 * math.sqrt(x * x + y * y + z * z))
        if best > tol:
            out[e, 0] = key // big
            out[e, 1] = key % big
            e += 1
        g = h
    return out[:e]


def site_pairs(sites: np.ndarray, box: np.ndarray, walls: np.ndarray) -> np.ndarray | None:
    """Pairs ``(p, q)`` of sites that are Voronoi neighbours (some repeated, maybe only one
    order of a pair); ``None`` when Qhull cannot triangulate (see the module's docstring)."""
    delaunay, qhull_error = qhull()
    u, d = sites.shape
    spacing = (float(np.prod(box)) / u) ** (1.0 / d)
    w = FIRST_MARGIN * spacing
    for _ in range(TRIES):
        pts, src = images(sites, box, walls, w)
        try:  # Qhull's options for Delaunay in scipy but Q12, which cost a third more time here
            tri = delaunay(pts, qhull_options="Qbb Qc Qz")
        except qhull_error:
            try:
                tri = delaunay(pts)
            except qhull_error:
                w *= 2.0
                continue
        simplices = tri.simplices.astype(np.int64)
        touching = np.any(simplices < u, axis=1)
        simplices = simplices[touching]
        centres, r2, flat = circumspheres(pts, simplices)
        need = margin_needed(centres[~flat], r2[~flat], box)
        if need.size and need.max() > w:
            w = 1.1 * float(need.max())
            continue
        edges = sides(simplices, flat, centres, u, TIE * spacing ** (d - 1))
        pairs = src[edges]
        if len(tri.coplanar):
            pairs = left_out(pairs, tri.coplanar, src, u)
        return pairs
    return None


def left_out(pairs: np.ndarray, coplanar: np.ndarray, src: np.ndarray, u: int) -> np.ndarray:
    """``pairs`` with the sites Qhull left out (``coplanar``: point, facet, nearest
    vertex) put in: each a neighbour of the vertex it names and of that vertex's neighbours."""
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    for point, _, vertex in coplanar:
        p, q = src[point], src[vertex]
        if point >= u or p == q:
            continue
        shared = pairs[(pairs[:, 0] == q) & (pairs[:, 1] != p), 1]
        pairs = np.concatenate([pairs, [[p, q]], np.stack([np.full_like(shared, p), shared], 1)])
    return pairs


@numba.njit(cache=True)
def compress(i, j, n):
    """The pairs ``(i, j)`` (either order, repeats, ``i == j`` allowed) as compressed rows of
    ``n`` particles: both orders, each once, no ``i == j``, each row in increasing order."""
    count = np.zeros(n + 1, dtype=np.int64)
    for e in range(i.shape[0]):
        if i[e] != j[e]:
            count[i[e] + 1] += 1
            count[j[e] + 1] += 1
    offsets = np.cumsum(count)
    fill = offsets[:-1].copy()
    nbrs = np.empty(offsets[n], dtype=np.int64)
    for e in range(i.shape[0]):
        if i[e] != j[e]:
            nbrs[fill[i[e]]] = j[e]
            fill[i[e]] += 1
            nbrs[fill[j[e]]] = i[e]
            fill[j[e]] += 1
    out = np.zeros(n + 1, dtype=np.int64)
    k = 0
    for r in range(n):
        row = np.sort(nbrs[offsets[r]:offsets[r + 1]])
        for c in range(row.shape[0]):
            if c == 0 or row[c] != row[c - 1]:
                nbrs[k] = row[c]
                k += 1
        out[r + 1] = k
    return out, nbrs[:k].copy()


def graph(pos: np.ndarray, box: np.ndarray, walls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Voronoi neighbours of particles at ``pos`` (``(d, n)``, in the box) as a
    compressed list: particle ``i``'s neighbours are ``nbrs[offsets[i]:offsets[i + 1]]``,
    in increasing order, ``i`` itself never among them."""
    d, n = pos.shape
    if n <= 1:
        return np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    points = np.ascontiguousarray(pos.T)
    order = np.lexsort(points.T[::-1])
    ranked = points[order]
    new_site = np.concatenate([[True], np.any(ranked[1:] != ranked[:-1], axis=1)])
    box, walls = np.asarray(box, dtype=np.float64), np.asarray(walls, dtype=bool)
    if new_site.all():  # no coincident particles: each particle a site, in slot order
        pairs = site_pairs(points, box, walls)
        if pairs is not None:
            return compress(pairs[:, 0], pairs[:, 1], n)
    else:
        first = np.flatnonzero(np.concatenate([new_site, [True]]))  # particles order[first[s]:first[s + 1]]
        pairs = site_pairs(ranked[new_site], box, walls)
        if pairs is not None:
            pairs = np.concatenate([pairs, np.stack([np.arange(len(first) - 1)] * 2, axis=1)])  # within a site
            i_parts, j_parts = [], []
            for p, q in pairs:
                a, b = order[first[p]:first[p + 1]], order[first[q]:first[q + 1]]
                i_parts.append(np.repeat(a, len(b)))
                j_parts.append(np.tile(b, len(a)))
            return compress(np.concatenate(i_parts), np.concatenate(j_parts), n)
    everyone = np.ones((n, n), dtype=bool)  # Qhull could not triangulate
    i, j = np.nonzero(everyone)
    return compress(i.astype(np.int64), j.astype(np.int64), n)
