"""Compile the CPU kernels the default suite uses before its workers start, each once.

A fresh checkout has no compiled kernels in numba's cache, and each of the suite's two
pytest-xdist workers compiled every kernel its tests met first: a kernel that both met
before either had cached it was compiled twice. Compiling each kernel (the variants of
:func:`flocking.backends.cpu_kernels.variant` that the suite's tests run, 2D and 3D,
``lines`` and ``search``) once, in as many processes as there are workers, before the
tests, leaves the workers to load them from the cache (a second each). The conftest does
it when the whole default suite runs on two or more workers; a run of chosen files
compiles what it meets, as before.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import flocking

SRC = os.path.dirname(os.path.dirname(flocking.__file__))

#: two species with a coupling
COUPLED = dict(species=[{"fraction": 0.5}, {"fraction": 0.5}], coupling=[[1.0, -1.0], [-1.0, 1.0]])

#: one small model per kernel the default suite runs (kernel, variant of
#: ``extended coupling nematic cone cohesion``), and the seconds its first step took to
#: compile on the project's 2-core machine, one at a time in a fresh process, on 2026-11-29
#: (the first, the plain model's, includes the cell sort that every kernel shares)
MODELS = [
    (36, dict(n=50, box=6.0)),  # lines_2d_00000
    (24, dict(n=50, box=6.0, boundary="wall")),  # lines_2d_10000
    (46, dict(n=50, box=6.0, cohesion=0.5)),  # lines_2d_10001
    (34, dict(n=50, box=6.0, vision=2.0)),  # lines_2d_10010
    (29, dict(n=50, box=6.0, alignment_rule="nematic")),  # lines_2d_10100
    (36, dict(n=50, box=6.0, **COUPLED)),  # lines_2d_11000
    (36, dict(n=50, box=6.0, vision=2.0, **COUPLED)),  # lines_2d_11010
    (25, dict(n=50, box=6.0, dim=3)),  # lines_3d_00000
    (27, dict(n=50, box=6.0, dim=3, boundary="wall")),  # lines_3d_10000
    (39, dict(n=50, box=6.0, neighbours="topological")),  # search_2d_00000
    (45, dict(n=50, box=6.0, neighbours="topological", boundary="wall")),  # search_2d_10000
    (44, dict(n=50, box=6.0, neighbours="topological", vision=2.0)),  # search_2d_11110
    (40, dict(n=50, box=6.0, dim=3, neighbours="topological")),  # search_3d_00000
    (26, dict(n=50, box=6.0, neighbours="voronoi")),  # graph_2d_00000
]


def kernel_of(kwargs: dict) -> str:
    """The kernel a model of ``kwargs`` runs on the cpu backend, as numba's cache names it:
    each of :data:`MODELS` its own.

    >>> kernel_of(MODELS[2][1])
    'lines_2d_10001'
    >>> len({kernel_of(kwargs) for _, kwargs in MODELS}) == len(MODELS)
    True
    """
    from flocking import Model
    from flocking.backends.cpu import kernel_name
    from flocking.backends.cpu_kernels import cache_tag, variant
    from flocking.backends.features import features

    model = Model(**kwargs)
    return f"{kernel_name(model)}_{cache_tag(variant(features(model), kernel_name(model)), model.dim)}"


#: what each process runs: two steps of each model it is given
CHILD = """
import json, sys
from flocking import Model, Simulation
for kwargs in json.loads(sys.argv[1]):
    Simulation(Model(**kwargs), backend="cpu").run(2)
"""


def shares(models: list[tuple[float, dict]], processes: int) -> list[list[dict]]:
    """``models`` split into ``processes`` lists of about equal cost, longest first.

    >>> shares([(3, {"a": 1}), (2, {"b": 2}), (2, {"c": 3})], 2)
    [[{'a': 1}], [{'b': 2}, {'c': 3}]]
    """
    out: list[list[dict]] = [[] for _ in range(processes)]
    cost = [0.0] * processes
    for seconds, kwargs in sorted(models, key=lambda m: -m[0]):
        p = cost.index(min(cost))
        out[p].append(kwargs)
        cost[p] += seconds
    return out


def compile_kernels(processes: int) -> tuple[float, list[str]]:
    """Compile (or load) every kernel of :data:`MODELS` in ``processes`` processes at once;
    the seconds it took and the errors of any process that failed (the tests then meet
    the failure themselves)."""
    start = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [SRC, os.environ.get("PYTHONPATH")]))}
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, json.dumps(share)], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True)
             for share in shares(MODELS, processes) if share]
    errors = []
    for p in procs:
        err = p.communicate()[1]
        if p.returncode != 0:
            errors.append((err.strip().splitlines() or [f"exit status {p.returncode}"])[-1])
    return time.perf_counter() - start, errors
