"""Clusters: particles linked when closer than ``radius`` (periodic, minimum image).

Union-find over a numba cell list, O(N) per frame. Labels are numbered by decreasing
size (0 is the largest cluster; ties by the lowest particle index).

>>> import numpy as np
>>> pts = np.array([[0.2, 5.0], [9.8, 5.0], [5.0, 5.0], [5.5, 5.0], [2.0, 8.0]])
>>> cl = Clusters(radius=1.0).compute((10.0, pts))   # 0 and 1 touch across x = 0
>>> cl.cluster_idx.tolist(), cl.sizes.tolist()
([0, 0, 1, 1, 2], [2, 2, 1])
"""

from __future__ import annotations

import numpy as np

from . import _cells, _input
from ._base import Analysis, positive, result


def labels(positions, box, radius: float) -> np.ndarray:
    """Cluster label of each particle, 0 for the largest cluster."""
    roots = _cells.cluster_roots(positions, box, radius)
    uniq, first, inverse, sizes = np.unique(roots, return_index=True, return_inverse=True, return_counts=True)
    rank = np.empty(len(uniq), np.int64)
    rank[np.lexsort((first, -sizes))] = np.arange(len(uniq))
    return rank[inverse.ravel()]


class Clusters(Analysis):
    """Cluster sizes and the largest-cluster fraction.

    Parameters
    ----------
    radius: link distance (strictly closer). Default: the trajectory's interaction radius
        when it stores one, else 1.
    start, frames: the window. Labels are those of the last frame; the size distribution
        and the largest fraction are over all frames of the window.
    """

    _keys = ("num_clusters", "largest_fraction", "largest_fraction_mean", "mean_size", "size_values",
             "size_counts", "radius_used", "num_frames")

    def __init__(self, radius=None, start=None, frames=None):
        self.radius = positive("radius", radius, allow_none=True)
        _input.window_start(start, [0], 1)
        self.start, self.frames = start, _input.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"radius": self.radius, "start": self.start, "frames": self.frames}

    cluster_idx = result("cluster_idx", "Label of each particle in the last frame (0 = largest).")
    sizes = result("sizes", "Cluster sizes in the last frame, largest first.")
    num_clusters = result("num_clusters", "Number of clusters in the last frame.")
    largest_fraction = result("largest_fraction", "Largest cluster / N in the last frame.")
    largest_fraction_mean = result("largest_fraction_mean", "Largest cluster / N averaged over frames.")
    mean_size = result("mean_size", "Number-weighted mean cluster size over frames.")
    size_values = result("size_values", "Distinct cluster sizes s over all frames.")
    size_counts = result("size_counts", "Number of clusters of each size, summed over frames.")
    radius_used = result("radius_used", "The link radius used.")
    num_frames = result("num_frames", "Number of frames.")

    def compute(self, system) -> Clusters:
        radius = self.radius
        if radius is None:
            model = _input.model_of(system)
            radius = model.radius if model is not None else 1.0
        frames = _input.select(_input.as_frames(system), self.start, self.frames)
        all_sizes, fractions = [], []
        for f in frames:
            lab = labels(f.positions, f.box, radius)
            sizes = np.bincount(lab)
            all_sizes.append(sizes)
            fractions.append(sizes[0] / f.n)
        values, counts = np.unique(np.concatenate(all_sizes), return_counts=True)
        self._store(cluster_idx=lab, sizes=sizes, num_clusters=len(sizes), largest_fraction=float(fractions[-1]),
                    largest_fraction_mean=float(np.mean(fractions)),
                    mean_size=float((values * counts).sum() / counts.sum()), size_values=values,
                    size_counts=counts, radius_used=float(radius), num_frames=len(frames))
        return self

    def plot(self, ax=None):
        """Number of clusters of each size, log-log."""
        ax = self._axis(ax)
        ax.loglog(self.size_values, self.size_counts / self.num_frames, "o", ms=4)
        ax.set_xlabel("cluster size s")
        ax.set_ylabel("clusters per frame")
        ax.set_title(f"largest fraction {self.largest_fraction_mean:.3f}")
        return ax
