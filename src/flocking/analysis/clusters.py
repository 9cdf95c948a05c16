"""Clusters: particles linked when closer than ``radius``, or (``k``) when one is among
the other's ``k`` nearest, the topological model's interaction graph.

Distances and nearest neighbours are those of the engine
(:meth:`flocking.space.Space.neighbours`): the minimum image along periodic axes, none
across a wall, so particles facing each other across a wall are not linked. Obstacles
hide no neighbour in the engine, so a link may cross one. Union-find over the pairs of a
cell list, O(N) per frame. Labels are numbered by decreasing size (0 is the largest
cluster; ties by the lowest particle index). Without ``radius`` or ``k`` the run's radius
links them, also for a topological run, whose graph of k nearest is nearly one cluster
for the usual k (in 20 000 uniform random points in 2D, k = 4 leaves 0.06 % outside the
largest cluster, k = 5 none).

Over the frames of the window, with ``n_s`` the number of clusters of size ``s`` summed
over all of them: the number-average size ``sum s n_s / sum n_s`` (the mean size of a
cluster) and the weight-average size ``sum s^2 n_s / sum s n_s`` (the mean size of the
cluster a particle belongs to, the one the percolation and flocking literature calls the
mean cluster size); the largest cluster's fraction of the particles, both in the last
frame and averaged over the frames.

>>> import numpy as np
>>> pts = np.array([[0.2, 5.0], [9.8, 5.0], [5.0, 5.0], [5.5, 5.0], [2.0, 8.0]])
>>> cl = Clusters(radius=1.0).compute((10.0, pts))   # 0 and 1 touch across x = 0
>>> cl.cluster_idx.tolist(), cl.sizes.tolist()
([0, 0, 1, 1, 2], [2, 2, 1])
>>> cl.number_average_size, cl.weight_average_size    # 5 / 3 and (4 + 4 + 1) / 5
(1.6666666666666667, 1.8)
>>> walled = Space((10.0, 10.0), walls=(True, False))
>>> Clusters(radius=1.0).compute((walled, pts)).sizes.tolist()  # a wall at x = 0 parts them
[2, 1, 1, 1]
>>> Clusters(k=1).compute((10.0, pts)).sizes.tolist()  # each with its nearest: 0-1, 2-3, and 4 with 0
[3, 2]
"""

from __future__ import annotations

import numba
import numpy as np

from ..checks import ParameterError, integer
from ..space import Space
from . import snapshots
from .base import Analysis, format_value, log_ticks, pair_notes, positive, result


@numba.njit(cache=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        parent[i], i = root, parent[i]
    return root


@numba.njit(cache=True)
def _join(parent, first, second):
    """Union of the sets of ``first[k]`` and ``second[k]`` for every k (the lower root wins)."""
    for k in range(len(first)):
        a = _find(parent, first[k])
        b = _find(parent, second[k])
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b


@numba.njit(cache=True)
def _roots(parent):
    for i in range(len(parent)):
        parent[i] = _find(parent, i)
    return parent


def labels(space: Space, positions, radius: float | None = None, k: int | None = None) -> np.ndarray:
    """Cluster label of each particle, 0 for the largest cluster: particles closer than
    ``radius`` in ``space`` are linked, or (``k`` given) each with its ``k`` nearest."""
    query = space.neighbours(positions)
    parent = np.arange(len(positions))
    if k is not None:
        nearest, _ = query.nearest(k)
        _join(parent, np.repeat(np.arange(len(positions)), k), nearest.ravel())
    else:
        for pairs in query.pair_blocks(radius):
            _join(parent, pairs.i, pairs.j)
    roots = _roots(parent)
    uniq, first, inverse, sizes = np.unique(roots, return_index=True, return_inverse=True, return_counts=True)
    rank = np.empty(len(uniq), np.int64)
    rank[np.lexsort((first, -sizes))] = np.arange(len(uniq))
    return rank[inverse.ravel()]


class Clusters(Analysis):
    """Cluster sizes and the largest-cluster fraction.

    Parameters
    ----------
    radius
        Link distance (strictly closer).
    k
        Instead of a distance: each particle is linked with its ``k`` nearest (ties to
        the lower index, as in the engine). Default (neither given): the trajectory's
        interaction radius when it stores one, else a radius of 1.
    start, frames
        The window. Labels are those of the last frame; the size distribution
        and the averages are over all frames of the window.
    """

    _keys = ("num_clusters", "largest_fraction", "largest_fraction_mean", "number_average_size",
             "weight_average_size", "size_values", "size_counts_total", "size_counts_per_frame", "radius_used",
             "k_used", "num_frames")

    def __init__(self, radius=None, k=None, start=None, frames=None):
        self.radius = positive("radius", radius, allow_none=True)
        self.k = None if k is None else integer("k", k, 1)
        if radius is not None and k is not None:
            raise ParameterError(f"k: links by distance or by the k nearest, not both (got radius={radius!r}, k={k!r})")
        snapshots.window_start(start, [0], 1)
        self.start, self.frames = start, snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"radius": self.radius, "k": self.k, "start": self.start, "frames": self.frames}

    cluster_idx = result("cluster_idx", "Label of each particle in the last frame (0 = largest).")
    sizes = result("sizes", "Cluster sizes in the last frame, largest first.")
    num_clusters = result("num_clusters", "Number of clusters in the last frame.")
    largest_fraction = result("largest_fraction", "Largest cluster / N in the last frame.")
    largest_fraction_mean = result("largest_fraction_mean", "Largest cluster / N averaged over the frames.")
    number_average_size = result("number_average_size", "sum s n_s / sum n_s over the frames.")
    weight_average_size = result("weight_average_size", "sum s^2 n_s / sum s n_s over the frames.")
    size_values = result("size_values", "Distinct cluster sizes s over all frames.")
    size_counts_total = result("size_counts_total", "n_s: clusters of each size, summed over the frames.")
    size_counts_per_frame = result("size_counts_per_frame", "n_s / frames: clusters of each size per frame.")
    radius_used = result("radius_used", "The link radius used (NaN when linked by the k nearest).")
    k_used = result("k_used", "The number of nearest others each particle is linked with (0 when linked by distance).")
    num_frames = result("num_frames", "Number of frames.")

    def compute(self, system) -> Clusters:
        radius, k = self.radius, self.k
        if radius is None and k is None:
            model = snapshots.model_of(system)
            radius = model.radius if model is not None else 1.0
        frames = snapshots.select(snapshots.as_frames(system), self.start, self.frames)
        if k is not None and k >= frames[-1].n:
            raise ParameterError(f"k: must be at most the number of other particles, {frames[-1].n - 1} (got {k})")
        all_sizes, fractions = [], []
        for f in frames:
            lab = labels(f.space, f.positions, radius, k)
            sizes = np.bincount(lab)
            all_sizes.append(sizes)
            fractions.append(sizes[0] / f.n)
        values, counts = np.unique(np.concatenate(all_sizes), return_counts=True)
        mass = (values * counts).sum()  # particles, summed over the frames
        self._store(cluster_idx=lab, sizes=sizes, num_clusters=len(sizes), largest_fraction=float(fractions[-1]),
                    largest_fraction_mean=float(np.mean(fractions)),
                    number_average_size=float(mass / counts.sum()),
                    weight_average_size=float((values.astype(float) ** 2 * counts).sum() / mass),
                    size_values=values, size_counts_total=counts, size_counts_per_frame=counts / len(frames),
                    radius_used=float("nan") if radius is None else float(radius), k_used=int(k or 0),
                    num_frames=len(frames),
                    notes=pair_notes(frames[-1].space, "no link"))
        return self

    def plot(self, ax=None, theme=None):
        """The number of clusters per frame and unit size, in bins of sizes 1, 2-3, 4-7, ...
        (doubling, so that the sparse large sizes are counted together), log-log, with the
        two average sizes marked; the legend above the tail of a falling distribution."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        edges = 2 ** np.arange(int(np.log2(max(self.size_values.max(), 1))) + 2)  # 1, 2, 4, ...
        per_bin = np.histogram(self.size_values, edges, weights=self.size_counts_per_frame)[0]
        width = np.diff(edges)
        shown = per_bin > 0
        ax.loglog(np.sqrt(edges[:-1] * (edges[1:] - 1))[shown], (per_bin / width)[shown], "o-", ms=3.5, lw=0.9,
                  color=colours[0], label=f"mean of {self.num_frames} frame{'s' * (self.num_frames > 1)}")
        ax.plot([], [], " ", color=colours[-1], label="sizes binned 1, 2-3, 4-7, ...")
        ax.axvline(self.number_average_size, color=colours[1], ls="--", lw=1,
                   label=rf"$\langle s\rangle_n = {format_value(self.number_average_size)}$")
        ax.axvline(self.weight_average_size, color=colours[2], ls=":", lw=1.2,
                   label=rf"$\langle s\rangle_w = {format_value(self.weight_average_size)}$")
        ax.plot([], [], " ", color=colours[-1], label=f"largest: {self.largest_fraction_mean:.3f} $N$")
        style.label_axes(ax, "cluster_size", r"clusters per frame and size $n(s)$")
        log_ticks(ax)
        style.legend(ax, theme, loc="upper right", frameon=True, facecolor=ax.get_facecolor(), edgecolor="none",
                     framealpha=0.8)
        return ax
