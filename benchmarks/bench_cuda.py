"""Throughput of the cuda backend against the targets of docs/gpu.md, and its kernels' resources.

On a machine with an NVIDIA GPU and ``pip install 'flocking[cuda]'``::

    python benchmarks/bench_cuda.py              # every case (a few minutes on an H100)
    python benchmarks/bench_cuda.py --quick      # every N / 10
    python benchmarks/bench_cuda.py --case clustered --case ensemble
    python benchmarks/bench_cuda.py --no-graphs  # every kernel launched from the host
    python benchmarks/bench_cuda.py --ptx        # no GPU needed: compile every kernel for
                                                 # sm_90, print registers, spills, shared memory
    NUMBA_ENABLE_CUDASIM=1 python benchmarks/bench_cuda.py --case 2d-float32 --scale 5e-6 --steps 1 --repeats 1
                                                 # smoke test of the script itself, no GPU

Each case builds its system(s), takes a few untimed steps (compilation, the CUDA graph),
then times ``--repeats`` chunks of ``--steps`` steps and prints the median particle-steps
per second (an ensemble's summed over replicas) beside its target. ``advance`` ends with a
copy of the polar order to the host, so the GPU has finished when the clock stops.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import flocking
from flocking.backends.cuda import CUDABackend

#: name -> (what, target particle-steps/s, or for a ratio ("delay", "extensions...") the ratio to the plain model)
CASES = {
    "2d-float32": ("2D, N = 1e7, density 2, float32", 5e9),
    "2d-float64": ("2D, N = 1e7, density 2, float64", 3.5e9),
    "3d": ("3D, N = 1e7, density 1, float32", 3.5e9),
    "clustered": ("2D, N = 1e6, noise 0.3, 600 steps from random, float64", 3e8),
    "small": ("2D, one system of N = 1e4, float64", 1e8),
    "ensemble": ("2D, 1024 replicas of N = 1024, seeds and noises differ, float32, summed", 3e9),
    "topological": ("2D, k = 7, N = 1e7, float32", 1.5e9),
    "delay": ("2D, delay 10 vs none, N = 1e7, float32: ratio", 0.8),
    "extensions": ("2D, every extension on vs none, N = 1e7, float32: ratio", 0.5),
    "extensions-but-cohesion": ("2D, every extension but cohesion vs none (the case of the trees before "
                                "cohesion), N = 1e7, float32: ratio", 0.5),
}


def timed(advance, steps: int, repeats: int, particles: int) -> float:
    """Median particle-steps per second of ``repeats`` calls ``advance(steps)``."""
    advance(2)  # compile, capture the graph
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        advance(steps)
        rates.append(steps * particles / (time.perf_counter() - t0))
    return statistics.median(rates)


def single(model: flocking.Model, precision: str, args, state: flocking.State | None = None) -> float:
    backend = CUDABackend(model, state or flocking.State.random(model), precision=precision,
                          graphs=not args.no_graphs)
    return timed(backend.advance, args.steps, args.repeats, model.n)


def run_case(name: str, args) -> float:
    scale = args.scale * (0.1 if args.quick else 1.0)
    big = max(int(1e7 * scale), 100)
    if name in ("2d-float32", "2d-float64"):
        return single(flocking.Model(n=big, density=2.0, noise=1.0, seed=1), name[3:], args)
    if name == "3d":
        return single(flocking.Model(dim=3, n=big, density=1.0, noise=1.0, seed=1), "float32", args)
    if name == "clustered":
        model = flocking.Model(n=max(int(1e6 * scale), 100), density=2.0, noise=0.3, seed=1)
        warm = CUDABackend(model, flocking.State.random(model), graphs=not args.no_graphs)
        warm.advance(600)
        return single(model, "float64", args, warm.state)
    if name == "small":
        return single(flocking.Model(n=10_000, density=2.0, noise=1.0, seed=1), "float64", args)
    if name == "ensemble":
        replicas = max(int(1024 * scale), 2) if args.quick else 1024
        noises = np.linspace(0.5, 4.0, replicas)
        models = [flocking.Model(n=1024, density=2.0, noise=float(eta), seed=r) for r, eta in enumerate(noises)]
        ens = flocking.Ensemble(models, backend="cuda", precision="float32")
        return timed(ens.advance, args.steps, args.repeats, 1024 * replicas)
    if name == "topological":
        return single(flocking.Model(n=big, density=2.0, noise=1.0, neighbours="topological", k=7, seed=1),
                      "float32", args)
    if name == "delay":
        plain = single(flocking.Model(n=big, density=2.0, noise=1.0, seed=1), "float32", args)
        delayed = single(flocking.Model(n=big, density=2.0, noise=1.0, delay=10, seed=1), "float32", args)
        print(f"  delay 10: {delayed:.3e}, none: {plain:.3e}")
        return delayed / plain
    if name in ("extensions", "extensions-but-cohesion"):
        # walls on y, an obstacle, two species that anti-align, a vision cone, nematic
        # alignment, cohesion, chirality and a field: every branch of the extended kernels
        plain = flocking.Model(n=big, density=2.0, noise=1.0, seed=1)
        side = plain.box[0]
        every = plain.replace(boundary="periodic,wall", obstacles=[{"centre": [side / 2, side / 2], "radius": side / 8}],
                              species=[{"fraction": 0.5}, {"fraction": 0.5, "noise": 2.0}],
                              coupling=[[1.0, -1.0], [-1.0, 1.0]], vision=2.1, alignment_rule="nematic",
                              chirality=0.1, field=[1.0, 0.0], field_strength=0.2,
                              cohesion=0.5 if name == "extensions" else 0.0)
        base, extended = single(plain, "float32", args), single(every, "float32", args)
        print(f"  {name}: {extended:.3e}, none: {base:.3e}")
        return extended / base
    raise ValueError(name)


def ptx_report() -> None:
    """Compile every kernel for sm_90 (numba's compiler, no GPU) and let ptxas report
    registers, spills and shared memory of each (needs the CUDA toolkit's ptxas)."""
    import types

    import numba.cuda.dispatcher as dispatcher
    from numba import cuda

    # device functions ask the current device for its compute capability: there is none
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(9, 0))
    from flocking.backends import cuda_kernels
    from flocking.backends.cuda_sort import Launch
    from flocking.backends.features import Features

    # the plain kernels, and those of a model with every extension (two species with a
    # coupling, nematic alignment, a vision cone, cohesion; walls, obstacles, field and
    # chirality are data)
    every = Features(extended=True, coupling=True, nematic=True, cone=True, cohesion=True)
    with tempfile.TemporaryDirectory() as folder:
        for precision, dim, k, (features, species) in [(p, d, k, e) for e in ((Features(), 1), (every, 2))
                                                      for p in ("float64", "float32") for d in (2, 3) for k in (0, 7)]:
            signatures = cuda_kernels.signatures(precision, dim, species)
            for delay in (False, True):
                kernels = cuda_kernels.build(precision, dim, k, Launch(256, 8, 8), features, species, delay)
                for name, signature in signatures.items():
                    if (k or delay) and name != "step":
                        continue  # only the step kernel depends on k and on the delay
                    kernel = getattr(kernels.sort if name in ("digits", "scatter") else kernels, name)
                    ptx, _ = cuda.compile_ptx(kernel.py_func, signature, cc=(9, 0))
                    path = f"{folder}/{name}.ptx"
                    with open(path, "w") as f:
                        f.write(ptx)
                    out = subprocess.run(["ptxas", "-arch=sm_90", "-v", path, "-o", "/dev/null"],
                                         capture_output=True, text=True).stderr
                    info = "; ".join(line.split("info    : ")[-1] for line in out.splitlines()
                                     if "Used" in line or "spill" in line)
                    label = ("extended" if features.extended else "plain") + (", delay" if delay else "")
                    print(f"{label} {precision} {dim}D k={k} {name:8s} {info}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", action="append", choices=list(CASES), help="run only these (repeatable)")
    parser.add_argument("--quick", action="store_true", help="every N divided by 10")
    parser.add_argument("--scale", type=float, default=1.0, help="multiply every N by this")
    parser.add_argument("--steps", type=int, default=50, help="steps per timed chunk")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-graphs", action="store_true", help="launch every kernel from the host")
    parser.add_argument("--ptx", action="store_true", help="compile for sm_90 and report resources; no GPU")
    args = parser.parse_args()
    if args.ptx:
        ptx_report()
        return

    from numba import cuda

    # the simulator has no device to name (a smoke test of this script: NUMBA_ENABLE_CUDASIM=1)
    device = cuda.get_current_device().name if hasattr(cuda, "get_current_device") else "CUDA simulator"
    device = device.decode() if isinstance(device, bytes) else device
    print(f"device: {device}; graphs: {not args.no_graphs}; {args.steps} steps x {args.repeats}, median")
    for name in args.case or CASES:
        what, target = CASES[name]
        try:
            value = run_case(name, args)
        except Exception as err:  # noqa: BLE001 - e.g. out of device memory: report and go on
            print(f"{name:12s} {what}: failed: {type(err).__name__}: {err}", flush=True)
            continue
        verdict = "ok" if value >= target else "MISSED"
        unit = "x" if what.endswith("ratio") else " particle-steps/s"
        print(f"{name:12s} {value:10.3e}{unit}  target {target:.1e}  {verdict}  ({what})", flush=True)


if __name__ == "__main__":
    sys.exit(main())
