"""Voronoi neighbours against the k = 7 topological step on the cpu backend (docs/voronoi.md).

Each case in its own backend, the cases interleaved repeat by repeat (so a change in the
machine's load hits them alike); the median seconds a step over ``--steps`` steps, after
one step that compiles. Also the cost of the lists alone: the cells cut in parallel
(2D) and Qhull's triangulation (2D and 3D).

    python benchmarks/bench_voronoi.py --n 10000 --n 100000 --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from flocking import Model, State
from flocking.backends import delaunay, voronoi_cells
from flocking.backends.cells import cell_grid
from flocking.backends.cpu import CPUBackend


def lists(model: Model, state: State) -> dict[str, float]:
    """Seconds to list the neighbours of ``state`` each way (the positions in id order)."""
    pos = np.ascontiguousarray(state.positions.T)
    box, walls = np.asarray(model.box), np.asarray(model.walls)
    out = {}
    t = time.perf_counter()
    delaunay.graph(pos, box, walls)
    out["qhull"] = time.perf_counter() - t
    if model.dim == 2:
        side = float(np.min(np.asarray(model.box) / cell_grid(model)))
        voronoi_cells.from_points(state.positions, box, walls, side)
        t = time.perf_counter()
        voronoi_cells.from_points(state.positions, box, walls, side)
        out["cells"] = time.perf_counter() - t
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, action="append", help="particles (repeatable; default 1e4 and 1e5)")
    parser.add_argument("--dim", type=int, action="append", help="2 or 3 (repeatable; default 2)")
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    for dim in args.dim or [2]:
        for n in args.n or [10_000, 100_000]:
            density = 2.0 if dim == 2 else 1.0
            cases = {name: Model(dim=dim, n=n, density=density, noise=0.5, seed=1, **kw)
                     for name, kw in (("voronoi", dict(neighbours="voronoi")),
                                      ("k=7", dict(neighbours="topological", k=7)))}
            backends = {name: CPUBackend(m, State.random(m)) for name, m in cases.items()}
            for b in backends.values():
                b.advance(1)
            times = {name: [] for name in cases}
            for _ in range(args.repeats):
                for name, b in backends.items():
                    t = time.perf_counter()
                    b.advance(args.steps)
                    times[name].append((time.perf_counter() - t) / args.steps)
            step = {name: statistics.median(v) for name, v in times.items()}
            parts = lists(cases["voronoi"], backends["voronoi"].state)
            print(f"{dim}D N={n}: voronoi {step['voronoi']:.4f} s/step ({n / step['voronoi']:.3g} particle-steps/s), "
                  f"k=7 {step['k=7']:.4f} s/step ({n / step['k=7']:.3g}); ratio {step['voronoi'] / step['k=7']:.1f}; "
                  + ", ".join(f"lists by {k} {v:.4f} s" for k, v in parts.items()), flush=True)


if __name__ == "__main__":
    main()
