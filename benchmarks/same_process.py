"""Two source trees in one process: each case's cost against the plain model, round by round.

``compare_trees.py`` alternates fresh processes; on a shared 2-core machine their speeds
still differ by 10 per cent or more from one process to the next, which hides changes of
a few per cent. Here the ``flocking`` package of each tree is copied under a name of its
own (its imports are relative) and both are imported into one process; every round
advances each tree's plain model and each case by a few steps, one after the other, and
the script reports medians over the rounds of per-round ratios, so that a slow moment of
the machine hits the numbers it divides alike::

    git worktree add /tmp/before HEAD~1
    python benchmarks/same_process.py /tmp/before/src src --cases cohesion --rounds 40
    python benchmarks/same_process.py /tmp/before/src src --cases cohesion --dim 3

A model that changes the state changes what its step costs: each model gathers the particles
at its own pace (2D, N = 10^5, density 2: 6.3 neighbours within ``R`` a particle at the
start; after 200 steps 13.7 with cohesion, 33.7 in the plain model). ``--same-state STEPS`` steps
every model of every tree, each round, from one state, the last case's after ``STEPS`` steps,
so that only the kernels differ::

    python benchmarks/same_process.py /tmp/before/src src --cases cohesion --same-state 60

Prints, per tree and case, the median (and quartiles) of ``plain time / case time`` (the
rate of the case against the plain model's) and the median of ``case time in the first
tree / case time in this tree`` (its speed against the first tree; the plain model's
too). Cases are those of
``bench_extensions.py``. Name a tree twice to see what the method itself scatters: two
copies of one tree, identical code, differed by up to 6 per cent in case time and by 0.02
in the rate against plain (2026-11-27, the project's 2-core machine).
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import statistics
import sys
import tempfile
import time

from bench_extensions import cases as extension_cases


def load(trees: list[str], into: str) -> list:
    """Each tree's ``flocking`` package copied into ``into`` as ``flocking_0``, ``flocking_1``,
    ...; returns the imported packages."""
    packages = []
    for t, tree in enumerate(trees):
        name = f"flocking_{t}"
        shutil.copytree(os.path.join(tree, "flocking"), os.path.join(into, name),
                        ignore=shutil.ignore_patterns("__pycache__"))
        packages.append(name)
    sys.path.insert(0, into)
    return [(importlib.import_module(p), importlib.import_module(p + ".backends.cpu")) for p in packages]


def split_cases(text: str, known) -> list[str]:
    """The case names in ``text``, separated by commas; a name that holds commas itself
    ("walls, cone, chirality, field") is taken whole, the longest known name first.

    >>> split_cases("cohesion,walls, cone, chirality, field", ["walls", "walls, cone, chirality, field", "cohesion"])
    ['cohesion', 'walls, cone, chirality, field']
    """
    found, rest = [], text.strip()
    while rest:
        name = max((k for k in known if rest == k or rest.startswith(k + ",")), key=len, default=None)
        if name is None:
            raise ValueError(rest.split(",")[0].strip())
        found.append(name)
        rest = rest[len(name) + 1:].strip()
    return found


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("trees", nargs="+", help="source folders holding a flocking package")
    parser.add_argument("--cases", default="cohesion",
                        help="comma-separated names from bench_extensions.py (names may hold commas themselves)")
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--density", type=float, default=2.0)
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--steps", type=int, default=5, help="steps per case and round")
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--same-state", type=int, default=0, metavar="STEPS",
                        help="restart every model, each round, from the last case's state after STEPS steps "
                             "(0: each model goes on from its own state)")
    args = parser.parse_args(argv)
    known = extension_cases(args.n, args.density, args.dim)
    try:
        names = ["plain"] + [c for c in split_cases(args.cases, known) if c != "plain"]
    except ValueError as unknown:
        parser.error(f"--cases: {str(unknown)!r} is not one of {'; '.join(known)}")
    side = (args.n / args.density) ** (1.0 / args.dim)
    if args.same_state < 0:
        parser.error(f"--same-state: {args.same_state} is not a number of steps (0 or more)")
    with tempfile.TemporaryDirectory() as folder:
        runs = {}
        packages = load(args.trees, folder)
        for t, (package, cpu) in enumerate(packages):
            for name in names:
                model = package.Model(n=args.n, dim=args.dim, box=side, seed=1, **known[name])
                runs[t, name] = cpu.CPUBackend(model, package.State.random(model))
                runs[t, name].advance(2)  # compiled (or loaded) before timing
        starts = None
        if args.same_state:  # one state for all, in each tree's own State (a backend copies what it is given)
            runs[0, names[-1]].advance(args.same_state)
            s = runs[0, names[-1]].state
            starts = [package.State(s.positions, s.headings, s.speeds, s.step) for package, _ in packages]
        times = {key: [] for key in runs}
        for _ in range(args.rounds):
            for key, backend in runs.items():
                if starts is not None:  # from the one state again: the kernels' cost alone is compared
                    backend = packages[key[0]][1].CPUBackend(backend.model, starts[key[0]])
                start = time.perf_counter()
                backend.advance(args.steps)
                times[key].append(time.perf_counter() - start)
    where = (f", every round from the state of {names[-1]!r} after {args.same_state} steps" if args.same_state
             else "")
    print(f"{args.dim}D, N = {args.n}, density {args.density}, {args.rounds} rounds of {args.steps} steps{where}, "
          f"{os.environ.get('NUMBA_NUM_THREADS', 'all')} threads")
    for t, tree in enumerate(args.trees):
        for name in names:
            rate = sorted(p / c for p, c in zip(times[t, "plain"], times[t, name]))
            speed = statistics.median(a / b for a, b in zip(times[0, name], times[t, name]))
            quarter = len(rate) // 4
            against = (f"against plain {statistics.median(rate):.3f} ({rate[quarter]:.3f}-{rate[-1 - quarter]:.3f})"
                       if name != "plain" else " " * 33)
            print(f"{tree:30s} {name:32s} {against}  speed against {args.trees[0]}: {speed:.3f}")


if __name__ == "__main__":
    main()
