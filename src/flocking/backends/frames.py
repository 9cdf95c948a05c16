"""The CPU backend's frame output: a frame's float32 positions and velocities in id order,
built in parallel from the cell-ordered arrays (what :class:`flocking.writers.GSDWriter`
writes).

>>> import numpy as np
>>> pos, head = np.array([[1.0, 3.0], [2.0, 2.0]]), np.array([[1.0, 0.0], [0.0, 1.0]])
>>> points, velocities = np.empty((2, 3), np.float32), np.empty((2, 3), np.float32)
>>> write_frame(pos, head, np.array([0.5]), np.array([1, 0], np.int32), np.array([4.0, 4.0]), points, velocities)
>>> points.tolist(), velocities.tolist()
([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], [[0.0, 0.5, 0.0], [0.5, 0.0, 0.0]])
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, parallel=True)
def write_frame(pos, head, spd, ids, box, points, velocities):
    """``points[id] = pos - L/2`` and ``velocities[id] = speed * head`` (float32, z = 0 in 2D),
    rounded from the same doubles as NumPy would."""
    d, n = pos.shape
    per_particle = spd.shape[0] == n and n > 1
    for s in numba.prange(n):
        i = ids[s]
        v = spd[s] if per_particle else spd[0]
        for a in range(3):
            if a < d:
                points[i, a] = np.float32(pos[a, s] - box[a] / 2.0)
                velocities[i, a] = np.float32(v * head[a, s])
            else:
                points[i, a] = np.float32(0.0)
                velocities[i, a] = np.float32(0.0)
