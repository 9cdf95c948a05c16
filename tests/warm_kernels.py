"""Compile the CPU backend's kernels into numba's cache before the tests start.

A fresh clone has no cache, and compiling the kernels is most of a first run of the suite.
``tests/conftest.py`` runs this script twice side by side when the whole suite starts (one
process per group below), so the two cores compile different kernels at once and every
test process then loads them from the cache instead of compiling them again::

    python tests/warm_kernels.py plain
    python tests/warm_kernels.py extensions

With a warm cache each takes a few seconds (loading only).
"""

from __future__ import annotations

import sys

#: per group, the Model keywords whose kernels the suite uses most
GROUPS = {
    "plain": [dict(), dict(dim=3), dict(delay=2, speeds="uniform"), dict(box=2.5),
              dict(neighbours="topological", k=3)],
    "extensions": [dict(boundary="wall"), dict(dim=3, vision=2.0, boundary="wall"),
                   dict(neighbours="topological", k=3, alignment_rule="nematic"), dict(box=2.5, chirality=0.1)],
}


def warm(group: str) -> None:
    from flocking import Model, State
    from flocking.backends.cpu import CPUBackend

    for options in GROUPS[group]:
        model = Model(**{"n": 60, "box": 5.0, "noise": 1.0, **options})
        backend = CPUBackend(model, State.random(model))
        backend.advance(2)
        backend.frame_arrays()


if __name__ == "__main__":
    warm(sys.argv[1])
