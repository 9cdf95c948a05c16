"""The usual SciPy approach to the Vicsek model, as a throughput reference.

One step: a periodic ``cKDTree(positions, boxsize=L)``, the sparse matrix of all pairs
closer than ``R`` (``sparse_distance_matrix``), its row sums against the headings, then
angular noise and the move, all in NumPy. This is what many research codes and blog posts
do; it is here only to be timed against ``flocking`` (see ``benchmarks/run.py``), and is
deliberately not part of the package.

>>> import numpy as np
>>> sim = KDTreeVicsek(np.random.default_rng(0).uniform(0, 10, (200, 2)), 10.0, noise=0.3)
>>> sim.advance(2).shape
(2,)
"""

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree


class KDTreeVicsek:
    """2D or 3D metric Vicsek model, angular noise, backward update, cubic box of side ``box``."""

    name = "kdtree"

    def __init__(self, positions, box, radius=1.0, speed=0.5, noise=0.5, dt=1.0, headings=None, seed=0):
        self.pos = np.array(positions, dtype=np.float64)
        n, self.dim = self.pos.shape
        self.box = float(box)
        self.radius, self.speed, self.noise, self.dt = radius, speed, noise, dt
        self.rng = np.random.default_rng(seed)
        if headings is None:
            headings = self.rng.normal(size=(n, self.dim))
        self.head = np.array(headings, dtype=np.float64)
        self.head /= np.linalg.norm(self.head, axis=1, keepdims=True)

    def step(self) -> None:
        tree = cKDTree(self.pos, boxsize=self.box)
        dist = tree.sparse_distance_matrix(tree, self.radius, output_type="coo_matrix")
        n = len(self.pos)
        # every pair closer than R, each particle with itself included
        a = sparse.csr_matrix((np.ones_like(dist.data), (dist.row, dist.col)), shape=(n, n))
        s = a @ self.head
        s /= np.linalg.norm(s, axis=1, keepdims=True)
        if self.dim == 2:
            angle = self.noise * self.rng.uniform(-0.5, 0.5, n)
            c, si = np.cos(angle), np.sin(angle)
            s = np.stack([s[:, 0] * c - s[:, 1] * si, s[:, 0] * si + s[:, 1] * c], axis=1)
        else:
            # vectorial-style perturbation in 3D, renormalised: the cost is what matters here
            s += self.noise * self.rng.normal(size=s.shape) / np.sqrt(3.0)
            s /= np.linalg.norm(s, axis=1, keepdims=True)
        self.head = s
        self.pos = np.mod(self.pos + self.speed * self.dt * s, self.box)

    def advance(self, steps: int) -> np.ndarray:
        phi = np.empty(steps)
        for t in range(steps):
            self.step()
            phi[t] = np.linalg.norm(self.head.mean(axis=0))
        return phi
