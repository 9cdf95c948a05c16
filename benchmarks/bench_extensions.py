"""What each extension costs on the CPU backend, against the plain model, in one process.

Every case starts from the same random state of the same size and density; cases run
interleaved, repeat by repeat, so that a slower moment of the machine hits all alike::

    python benchmarks/bench_extensions.py --n 100000 --repeats 3
    python benchmarks/bench_extensions.py --n 100000 --repeats 3 --dim 3

Prints particle-steps per second (best repeat) and the ratio to the plain model.
"""

from __future__ import annotations

import argparse
import time

import flocking
from flocking.backends.cpu import CPUBackend


def cases(n: int, density: float, dim: int = 2) -> dict[str, dict]:
    """Model arguments of each case: the plain model, one extension at a time (chirality in
    2D only), then combinations."""
    side = (n / density) ** (1.0 / dim)
    field = [1.0, 0.0, 0.0][:dim]
    found = {
        "plain": {},
        "walls": dict(boundary="wall"),
        "obstacle": dict(obstacles=[{"centre": [side / 2] * dim, "radius": side / 8}]),
        "two species, coupling": dict(species=[{"fraction": 0.5}, {"fraction": 0.5, "noise": 2.0}],
                                      coupling=[[1.0, -1.0], [-1.0, 1.0]]),
        "vision 2.1": dict(vision=2.1),
        "nematic": dict(alignment_rule="nematic"),
        "chirality 0.1": dict(chirality=0.1),
        "field": dict(field=field, field_strength=0.2),
        "cohesion": dict(cohesion=1.0),
        "walls, cone, chirality, field": dict(boundary="wall", vision=2.1, chirality=0.1, field=field,
                                              field_strength=0.2),
        "every extension": dict(boundary="periodic,wall", obstacles=[{"centre": [side / 2] * dim, "radius": side / 8}],
                                species=[{"fraction": 0.5}, {"fraction": 0.5, "noise": 2.0}],
                                coupling=[[1.0, -1.0], [-1.0, 1.0]], vision=2.1, alignment_rule="nematic",
                                chirality=0.1, field=field, field_strength=0.2, cohesion=1.0),
    }
    if dim == 3:
        for name in ("chirality 0.1", "walls, cone, chirality, field"):
            del found[name]
        found["every extension"].pop("chirality")
        found["every extension"]["boundary"] = "periodic,periodic,wall"
        found["walls, cone, field"] = dict(boundary="wall", vision=2.1, field=field, field_strength=0.2)
    return found


def backend(extra: dict, n: int, density: float, dim: int) -> CPUBackend:
    """A cpu backend of a case (``extra``: its model arguments, from :func:`cases`) from a
    random state: ``n`` particles at ``density`` in ``dim`` dimensions, noise 1, seed 1."""
    model = flocking.Model(n=n, dim=dim, density=density, noise=1.0, seed=1, **extra)
    return CPUBackend(model, flocking.State.random(model))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--density", type=float, default=2.0)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    args = parser.parse_args(argv)
    backends = {}
    for name, extra in cases(args.n, args.density, args.dim).items():
        backends[name] = backend(extra, args.n, args.density, args.dim)
        backends[name].advance(2)  # compile (or load) the kernels
    best = dict.fromkeys(backends, float("inf"))
    for _ in range(args.repeats):
        for name, stepped in backends.items():
            start = time.perf_counter()
            stepped.advance(args.steps)
            best[name] = min(best[name], time.perf_counter() - start)
    print(f"{args.dim}D, N = {args.n}, density {args.density}, best of {args.repeats} x {args.steps} steps\n")
    print("| case | particle-steps/s | against plain |\n| --- | ---: | ---: |")
    for name, seconds in best.items():
        print(f"| {name} | {args.steps * args.n / seconds:.3g} | {best['plain'] / seconds:.2f}x |")


if __name__ == "__main__":
    main()
