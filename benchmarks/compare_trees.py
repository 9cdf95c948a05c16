"""Throughput of the CPU backend in two source trees, interleaved run by run.

A change to the engine must not make the plain model slower. Comparing two numbers taken
minutes apart on a shared machine says little, so this script alternates the two trees in
fresh processes (each with its own numba cache, kernels compiled before timing) and reports,
per case, the best and the median of each tree's runs and their ratios::

    git worktree add /tmp/before HEAD~1
    python benchmarks/compare_trees.py /tmp/before/src src --rounds 3
    python benchmarks/compare_trees.py /tmp/before/src src --rounds 3 --extensions

(``--extensions``: the cases of ``bench_extensions.py``, 2D, N = 1e5, instead of the plain
model's.)

A ratio of 1.00 means equal; on the project's 2-core machine, runs of one tree differ by
about 10 per cent, so only a ratio outside [0.9, 1.1] in every round means something.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

from bench_extensions import cases as extension_cases

#: (label, Model keyword arguments); sizes that take a second or two a case
CASES = [
    ("2D metric N=1e5", dict(dim=2, n=100_000, density=2.0, noise=1.0)),
    ("2D metric N=1e6", dict(dim=2, n=1_000_000, density=2.0, noise=1.0)),
    ("2D delay 5 N=3e5", dict(dim=2, n=300_000, density=2.0, noise=1.0, delay=5)),
    ("2D topological N=1e5", dict(dim=2, n=100_000, density=2.0, noise=1.0, neighbours="topological")),
    ("3D metric N=1e5", dict(dim=3, n=100_000, density=1.0, noise=1.0)),
    ("3D metric N=1e6", dict(dim=3, n=1_000_000, density=1.0, noise=1.0)),
]

#: the extensions of ``bench_extensions.py``, one at a time and combined, 2D, N = 1e5
EXTENSION_CASES = [(label, dict(dim=2, n=100_000, density=2.0, noise=1.0, **extra))
                   for label, extra in extension_cases(100_000, 2.0).items()]

#: what each child process runs: compile, then time ``steps`` steps ``repeats`` times
CHILD = """
import json, sys, time
sys.path.insert(0, sys.argv[1])
import flocking
from flocking.backends.cpu import CPUBackend
out = {}
for label, kwargs in json.loads(sys.argv[2]):
    model = flocking.Model(seed=1, **kwargs)
    backend = CPUBackend(model, flocking.State.random(model))
    backend.advance(2)
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        backend.advance(10)
        best = min(best, time.perf_counter() - start)
    out[label] = 10 * model.n / best
print(json.dumps(out))
"""


def measure(src: str, cache: str, cases: list) -> dict[str, float]:
    """Particle-steps per second of every case of ``cases`` with the package in ``src``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    result = subprocess.run([sys.executable, "-c", CHILD, os.path.abspath(src), json.dumps(cases)],
                            env=env, capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", help="the src folder of the tree to compare against")
    parser.add_argument("after", help="the src folder of the changed tree")
    parser.add_argument("--rounds", type=int, default=3, help="alternations of the two trees")
    parser.add_argument("--extensions", action="store_true", help="the extensions' cases, not the plain model's")
    args = parser.parse_args(argv)
    cases = EXTENSION_CASES if args.extensions else CASES
    runs = {"before": {}, "after": {}}
    with tempfile.TemporaryDirectory() as scratch:
        for r in range(args.rounds):
            for name in ("before", "after"):
                rates = measure(getattr(args, name), os.path.join(scratch, name), cases)
                print(f"round {r + 1} {name}: " + ", ".join(f"{k} {v:.3g}" for k, v in rates.items()), flush=True)
                for k, v in rates.items():
                    runs[name].setdefault(k, []).append(v)
    print("\n| case | before, best (particle-steps/s) | after, best | after / before: best | median |\n"
          "| --- | ---: | ---: | ---: | ---: |")
    for label, _ in cases:
        b, a = runs["before"][label], runs["after"][label]
        print(f"| {label} | {max(b):.3g} | {max(a):.3g} | {max(a) / max(b):.2f} | "
              f"{statistics.median(a) / statistics.median(b):.2f} |")


if __name__ == "__main__":
    main()
