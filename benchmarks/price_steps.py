"""The cost of one step per particle and per neighbour candidate, by kernel: the numbers
behind the step prices of ``flocking play`` (flocking/play/budget.py, docs/play.md).

Each case takes single steps on one thread at N = 10^4 and density 2, once spread over the
box and once crowded into 2 % of it; two times and two candidate counts give the cost per
particle and per candidate::

    python benchmarks/price_steps.py
"""

from __future__ import annotations

import time

import numba
import numpy as np

from flocking import Model, State
from flocking.backends.cpu import CPUBackend

CASES = {
    "plain": {},
    "walls and chirality": dict(boundary="wall", chirality=0.1),
    "vision cone 2.0": dict(vision=2.0),
    "two coupled species, nematic": dict(species=[{"fraction": 0.5}, {"fraction": 0.5}],
                                         coupling=[[1.0, -1.0], [-1.0, 1.0]], alignment_rule="nematic"),
}


def best_step(model: Model, state: State, repeats: int = 5) -> float:
    """The fastest of ``repeats`` single steps from ``state``, in seconds."""
    CPUBackend(model, state).advance(1)  # compile (or load) the kernels
    best = float("inf")
    for _ in range(repeats):
        backend = CPUBackend(model, state)
        start = time.perf_counter()
        backend.advance(1)
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    numba.set_num_threads(1)
    n = 10_000
    print("| case | spread (ms) | crowded (ms) | ns per particle | ns per candidate |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for name, extra in CASES.items():
        model = Model(n=n, density=2.0, noise=1.0, seed=1, **extra)
        times, counts = [], []
        for crowded in (False, True):
            state = State.random(model)
            if crowded:
                side = model.box[0]
                state.positions[:] = np.random.default_rng(1).uniform(0.2 * side, 0.34 * side, size=(n, 2))
            times.append(best_step(model, state) * 1e9)
            counts.append(CPUBackend.step_cost(model, state.positions)[1] * n)
        particle, candidate = np.linalg.solve([[n, counts[0]], [n, counts[1]]], times)
        print(f"| {name} | {times[0] / 1e6:.1f} | {times[1] / 1e6:.1f} | {particle:.0f} | {candidate:.1f} |")


if __name__ == "__main__":
    main()
