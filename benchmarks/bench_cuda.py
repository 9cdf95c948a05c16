"""Throughput of the cuda backend against its targets and the cpu backend on all host cores.

Run it on a machine with an NVIDIA GPU and ``pip install 'flocking[cuda]'``::

    python benchmarks/bench_cuda.py            # the cases of the targets (N = 1e7, 1e8)
    python benchmarks/bench_cuda.py --quick    # N / 10, a minute or so
    python benchmarks/bench_cuda.py --init aligned --noise 0.3   # the ordered regime
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/bench_cuda.py --scale 3e-6 --steps 1 --repeats 1
                                               # smoke test of the script, no GPU (slow)

Each case builds the system, takes a few untimed steps (compilation, caches), then times
``--repeats`` chunks of ``--steps`` steps and prints the median particle-steps per second.
The cpu backend runs the same model (fewer steps) for the side-by-side column.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import flocking
from flocking.backends import get

#: (label, dim, N, precision, target particle-steps/s or None)
CASES = [
    ("2D metric", 2, 10**7, "float32", 1e9),
    ("2D metric", 2, 10**7, "float64", 5e8),
    ("3D metric", 3, 10**7, "float64", 3e8),
    ("3D metric", 3, 10**7, "float32", None),
    ("2D metric", 2, 10**8, "float32", None),
]


def rate(backend_name: str, model: flocking.Model, init: str, steps: int, repeats: int,
         **options) -> float:
    """Median particle-steps per second of ``repeats`` timed chunks of ``steps`` steps."""
    state = flocking.State.aligned(model) if init == "aligned" else flocking.State.random(model)
    backend = get(backend_name)(model, state, **options)
    backend.advance(2)  # compile and warm up
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        backend.advance(steps)  # ends with a device-to-host copy: the GPU is done
        rates.append(steps * model.n / (time.perf_counter() - t0))
    return statistics.median(rates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="every N divided by 10")
    parser.add_argument("--scale", type=float, default=1.0, help="multiply every N by this")
    parser.add_argument("--steps", type=int, default=20, help="steps per timed chunk (gpu)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu-steps", type=int, default=3, help="steps per timed chunk (cpu)")
    parser.add_argument("--no-cpu", action="store_true", help="skip the cpu column")
    parser.add_argument("--density", type=float, default=2.0)
    parser.add_argument("--noise", type=float, default=1.0)
    parser.add_argument("--init", choices=["random", "aligned"], default="random")
    args = parser.parse_args()

    from numba import cuda

    name = cuda.get_current_device().name if hasattr(cuda, "get_current_device") else "CUDA simulator"
    name = name.decode() if isinstance(name, bytes) else name
    print(f"device: {name}; host cores: {os.cpu_count()}; density {args.density}, noise {args.noise}, init {args.init}")
    header = f"{'case':<10} {'N':>9} {'precision':<9} {'cuda':>10} {'target':>8} {'cpu':>10} {'cuda/cpu':>8}"
    print(header)
    print("-" * len(header))
    cpu_cache: dict = {}
    for label, dim, n, precision, target in CASES:
        n = max(int(n * args.scale * (0.1 if args.quick else 1.0)), 10)
        model = flocking.Model(dim=dim, n=n, density=args.density, noise=args.noise, seed=1)
        try:
            gpu = rate("cuda", model, args.init, args.steps, args.repeats, precision=precision)
        except Exception as err:  # noqa: BLE001 - e.g. out of device memory: report and go on
            print(f"{label:<10} {n:>9.0e} {precision:<9} failed: {type(err).__name__}: {err}")
            continue
        cpu = None
        if not args.no_cpu and n <= 10**7:  # N = 1e8 on the cpu: minutes per step
            key = (dim, n)
            if key not in cpu_cache:
                cpu_cache[key] = rate("cpu", model, args.init, args.cpu_steps, args.repeats)
            cpu = cpu_cache[key]
        flag = "" if target is None else ("ok" if gpu >= target else "MISSED")
        print(f"{label:<10} {n:>9.0e} {precision:<9} {gpu:>10.3e} "
              f"{'' if target is None else f'{target:.0e}':>8} "
              f"{'' if cpu is None else f'{cpu:.3e}':>10} {'' if cpu is None else f'{gpu / cpu:.1f}x':>8} {flag}")


if __name__ == "__main__":
    main()
