"""Where a cuda step's time goes: each kernel of a step timed alone, and the speed of each
extension against the plain model.

On a machine with an NVIDIA GPU and ``pip install 'flocking[cuda]'``::

    python benchmarks/cuda_anatomy.py            # N = 1e7 (over three minutes on an H100)
    python benchmarks/cuda_anatomy.py --scale 0.1

Each kernel of a step is launched from the host between two ``cuda.synchronize()``
calls (the median of 10 steps), in the order of a step, so the state advances as it
does in a run; beside the sum, whole steps of the same system (host launches; an
ensemble's replayed as a CUDA graph). Then each extension alone, and all of them, against the plain model
(float32, 2D and 3D): particle-steps per second, the median of three chunks of 20 steps.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bench_cuda import timed

import flocking
from flocking.backends.cuda import CUDABackend, Engine

#: steps per timed chunk and chunks (the median is taken) of every rate below
STEPS, REPEATS = 20, 3


def sync_time(cuda, fn) -> float:
    cuda.synchronize()
    t0 = time.perf_counter()
    fn()
    cuda.synchronize()
    return time.perf_counter() - t0


def anatomy(label: str, engine: Engine, steps: int = 10) -> None:
    """Print each kernel's median time in a step of ``engine`` (its launches, in order,
    each timed alone), then the rate of whole steps as it takes them."""
    from numba import cuda

    m = engine.replicas * engine.n
    acc: dict[str, list[float]] = {}
    for _ in range(steps):
        for name, launch in engine.launches():
            acc.setdefault(name, []).append(sync_time(cuda, launch))
    med = {key: float(np.median(v)) for key, v in acc.items()}
    total = sum(med.values())
    how = "as a graph" if engine.graphs else "host launches"
    whole = timed(engine.advance, STEPS, REPEATS, m)
    passes = sum(name.startswith("scatter") for name in med)
    print(f"{label}: M = {m}, {passes} passes; kernels {total * 1e3:.3f} ms ({m / total:.3e}/s); "
          f"whole steps ({how}) {m / whole * 1e3:.3f} ms ({whole:.3e}/s)", flush=True)
    print("   " + "  ".join(f"{key} {v * 1e3:.3f} ms ({100 * v / total:.0f}%)" for key, v in med.items()), flush=True)


def extension_rates(plain: flocking.Model) -> None:
    """Each extension alone and all together against ``plain``, float32."""
    dim, side = plain.dim, plain.box[0]
    one = {"walls": dict(boundary=",".join(["periodic", "wall", "periodic"][:dim])),
           "obstacle": dict(obstacles=[{"centre": [side / 2] * dim, "radius": side / 8}]),
           "species": dict(species=[{"fraction": 0.5}, {"fraction": 0.5, "noise": 2.0}]),
           "coupling": dict(species=[{"fraction": 0.5}, {"fraction": 0.5}], coupling=[[1.0, -1.0], [-1.0, 1.0]]),
           "vision": dict(vision=2.1), "nematic": dict(alignment_rule="nematic"),
           "field": dict(field=[1.0] + [0.0] * (dim - 1), field_strength=0.2)}
    if dim == 2:
        one["chirality"] = dict(chirality=0.1)
    one["every"] = {key: value for kw in list(one.values()) for key, value in kw.items()}
    base = timed(CUDABackend(plain, flocking.State.random(plain), precision="float32").advance, STEPS, REPEATS,
                 plain.n)
    print(f"{dim}D float32 plain      {base:.3e}/s", flush=True)
    for name, kw in one.items():
        model = plain.replace(**kw)
        r = timed(CUDABackend(model, flocking.State.random(model), precision="float32").advance, STEPS, REPEATS,
                  model.n)
        print(f"{dim}D float32 {name:10s} {r:.3e}/s  {r / base:.2f}x", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="multiply every N by this")
    args = parser.parse_args()
    big = max(int(1e7 * args.scale), 200)
    plain2 = flocking.Model(n=big, density=2.0, noise=1.0, seed=1)
    plain3 = flocking.Model(dim=3, n=big, density=1.0, noise=1.0, seed=1)
    for label, model, precision in [("2D float32", plain2, "float32"), ("2D float64", plain2, "float64"),
                                    ("3D float32", plain3, "float32"),
                                    ("2D float32, delay 10", plain2.replace(delay=10), "float32"),
                                    ("2D float32, k = 7", plain2.replace(neighbours="topological", k=7), "float32")]:
        anatomy(label, Engine([model], [flocking.State.random(model)], precision=precision, graphs=False))
    replicas = max(2, int(1024 * min(1.0, args.scale * 10)))
    models = [flocking.Model(n=1024, density=2.0, noise=float(eta), seed=r)
              for r, eta in enumerate(np.linspace(0.5, 4.0, replicas))]
    anatomy(f"{replicas} replicas of 1024, float32",
            Engine(models, [flocking.State.random(x) for x in models], precision="float32"))
    clustered = flocking.Model(n=max(int(1e6 * args.scale), 200), density=2.0, noise=0.3, seed=1)
    warm = CUDABackend(clustered, flocking.State.random(clustered))
    warm.advance(600)
    anatomy("2D clustered (600 steps at noise 0.3), float64", Engine([clustered], [warm.state], graphs=False))
    extension_rates(plain2)
    extension_rates(plain3)


if __name__ == "__main__":
    main()
