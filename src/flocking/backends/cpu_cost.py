"""What a step of the cpu backend costs, priced before it runs from where the particles are
(:meth:`flocking.backends.cpu.CPUBackend.step_cost`, which the playground's budget asks).

The kernels visit, for every particle, the particles of the ``3^d`` cells around its own,
so a step costs about ``n * particle + candidates * candidate`` nanoseconds, where
``candidates`` is the sum over cells of ``n_c`` times the particles in the block of cells
around ``c`` (:func:`candidates`). A flock spread evenly over the box at density 2 has about
19 candidates a particle; all of it packed into one cell has ``n``. :data:`COSTS` holds the
nanoseconds per particle and per candidate of each kind of step (:func:`kind`). A model with
extensions (:attr:`flocking.Model.extended`: walls, obstacles, species, a vision cone,
chirality) runs a step compiled for them (dearer where each pair is weighted), and each
obstacle adds :data:`OBSTACLE_COST` per particle.

>>> from flocking import Model, State
>>> model = Model(n=4000, density=2.0)
>>> seconds, per_particle = step_cost(model, State.random(model).positions, "lines")
>>> round(per_particle)  # 9 cells of about 2.2 particles around each particle
20
>>> step_cost(model, np.full((4000, 2), 0.5), "lines")[1]  # every particle in one cell
4000.0
"""

from __future__ import annotations

import numpy as np

from ..model import Model
from ..rules import cached
from ..rules import compile as compile_rules
from . import cells
from .features import features

R = compile_rules("cpu")

#: nanoseconds of one core per particle and per neighbour candidate in a step, by kernel
#: (``topological``: per particle and neighbour sought, ``k + 1``); measured on the
#: project's 2-core machine while other programs kept it busy, so rather high. In 3D a
#: particle costs twice as much. The extended steps (any extension on) were measured
#: against the plain one on one thread, N = 10^4 at density 2, spread out and crowded into
#: 2 % of the box (docs/play.md): on a metric grid of at least three cells a side, without
#: pair weights as the plain step (walls and chirality: 200 ns and 1.8 ns measured), with
#: them (a coupling matrix, nematic alignment, a vision cone) about 1.2 times per particle
#: and 2 to 3 times per candidate (220 to 310 ns and 3.4 to 5 ns);
#: elsewhere (a box under ``3R``) 7 times the plain cost per particle, 20 times per candidate.
COSTS = {"lines": (300.0, 2.0), "generic": (300.0, 25.0), "topological": (250.0, 2.5),
         "extended lines": (300.0, 2.5), "extended weighted": (350.0, 6.0),
         "extended": (2500.0, 50.0), "extended topological": (450.0, 15.0),
         "voronoi": (22000.0, 0.0)}  # Qhull's triangulation, serial: 2.2 s a step at N = 1e5 (docs/voronoi.md)
#: nanoseconds per particle and obstacle: each particle is tested against every obstacle
OBSTACLE_COST = 25.0


def kind(model: Model, kernel: str) -> str:
    """Which of :data:`COSTS` prices ``model``'s step, given the kernel that runs it
    (``lines``, ``search`` or ``graph``, :func:`flocking.backends.cpu.kernel_name`) and what it
    compiles in (:func:`flocking.backends.features.features`): ``lines`` (metric, at
    least three cells a side), ``generic`` (metric, a box under ``3R`` along some axis),
    ``topological``, or with any extension ``extended lines`` (no pair weights),
    ``extended weighted`` (a coupling matrix, nematic alignment, a vision cone or
    cohesion), ``extended`` (a box under ``3R``), ``extended topological`` and ``voronoi``.

    >>> kind(Model(n=100, box=10.0), "lines"), kind(Model(n=100, box=10.0, boundary="wall"), "lines")
    ('lines', 'extended lines')
    >>> kind(Model(n=100, box=10.0, vision=2.0), "lines"), kind(Model(n=100, box=2.5, vision=2.0), "search")
    ('extended weighted', 'extended')
    """
    on = features(model)
    if kernel == "lines":
        if not on.extended:
            return "lines"
        return "extended weighted" if on.weighted else "extended lines"
    if model.neighbours == "voronoi":
        return "voronoi"
    if model.neighbours == "topological":
        return "extended topological" if on.extended else "topological"
    return "extended" if on.extended else "generic"


def step_cost(model: Model, positions: np.ndarray, kernel: str) -> tuple[float, float]:
    """Estimated seconds of one core for one step of ``kernel`` from ``positions`` (N, d),
    and the neighbour candidates per particle that the estimate counted."""
    n, d = positions.shape
    nc = cells.cell_grid(model)
    around = candidates(np.ascontiguousarray(positions.T), nc, nc / np.asarray(model.box, dtype=np.float64))
    name = kind(model, kernel)
    particle, candidate = COSTS[name]
    if name.endswith("topological"):
        particle *= model.k + 1
    particle *= 1 if d == 2 else (5.5 if name == "voronoi" else 2)  # 3D Voronoi: 1.2 s at N = 1e4
    particle += OBSTACLE_COST * len(model.obstacles)
    return (n * particle + around * candidate) * 1e-9, around / max(n, 1)


@cached(cells)
def candidates(pos, nc, inv):
    """Sum over cells of ``n_c`` times the particles in the cells around ``c``, each
    neighbouring cell counted once (a grid of one or two cells a side has fewer);
    ``pos[a, i]``, cells as the backend numbers them (:func:`flocking.backends.cells.cell_of`)."""
    d, n = pos.shape
    counts = np.zeros(np.prod(nc))
    for i in range(n):
        counts[cells.cell_of(pos, i, nc, inv)] += 1.0
    span = np.minimum(nc, 3)  # distinct neighbouring cells per axis
    ny = nc[1]
    nz = nc[2] if d == 3 else 1
    total = 0.0
    for c in range(counts.shape[0]):
        if counts[c] == 0.0:
            continue
        cx, cy, cz = R.cell_coords(c, nc[0], ny)
        around = 0.0
        for kz in range(span[2] if d == 3 else 1):
            z = (cz + kz - 1 + nz) % nz if d == 3 else 0
            for ky in range(span[1]):
                y = (cy + ky - 1 + ny) % ny
                for kx in range(span[0]):
                    x = (cx + kx - 1 + nc[0]) % nc[0]
                    around += counts[R.cell_number(x, y, z, nc[0], ny)]
        total += counts[c] * around
    return total
