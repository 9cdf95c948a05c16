"""flocking play compiles ahead: after its warm-up, nothing a page can switch on compiles
again (the first obstacle dropped froze a fresh install's flock for 21 s while numba
compiled the extended kernels)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("starlette", reason="the play extra is not installed (pip install 'flocking[play]')")

from flocking import Model  # noqa: E402
from flocking.play import server  # noqa: E402

SRC = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, "src"))

#: what a page's controls switch on, each alone, and combinations of them that the warm-up
#: covers (as parameters of a small model; cohesion with a pair weight, and combinations with
#: topological neighbours or in 3D, compile when first asked for, and the page says so:
#: tests/test_play_browser.py)
PAGE = [
    {"obstacles": [{"centre": [4.0, 4.0], "radius": 1.0}]},
    {"boundary": "wall,periodic"},
    {"boundary": "periodic,wall"},
    {"boundary": "wall"},
    {"species": [{"name": "A", "fraction": 0.5}, {"name": "B", "fraction": 0.5, "speed": 1.0, "noise": 2.0}],
     "coupling": [[1.0, -1.0], [-1.0, 1.0]]},
    {"species": [{"name": "A", "fraction": 0.5}, {"name": "B", "fraction": 0.5, "speed": 1.0, "noise": 2.0}]},
    {"vision": 1.0},
    {"chirality": 0.2},
    {"cohesion": 2.0},
    {"cohesion": 2.0, "chirality": 0.2, "boundary": "wall"},
    {"vision": 1.0, "chirality": 0.2, "boundary": "wall"},
    {"vision": 1.0, "species": [{"name": "A", "fraction": 0.5}, {"name": "B", "fraction": 0.5}],
     "coupling": [[1.0, -1.0], [-1.0, 1.0]], "obstacles": [{"centre": [4.0, 4.0], "radius": 1.0}]},
    {"neighbours": "topological", "k": 7},
    {"neighbours": "topological", "k": 7, "obstacles": [{"centre": [4.0, 4.0], "radius": 1.0}]},
    {"noise_type": "vectorial", "noise": 0.5},
    {"delay": 5},
    {"dim": 3},
    {"dim": 3, "boundary": "periodic,periodic,wall"},
]

#: a fresh process: warm up, then count the signatures every numba function of flocking
#: holds before and after one run of each of the page's settings
PROBE = """
import json, sys
from numba.core.registry import CPUDispatcher
from flocking import Model, Simulation
from flocking.play.server import warm_kernels

def dispatchers():
    import gc
    for obj in gc.get_objects():
        try:
            if isinstance(obj, CPUDispatcher) and (obj.py_func.__module__ or "").startswith("flocking"):
                yield obj
        except ReferenceError:  # a weak proxy whose object is gone
            continue

def signatures():
    # every numba function of flocking, the kernels compiled per feature set included
    return {f"{obj.py_func.__module__}.{obj.py_func.__qualname__}#{id(obj)}": len(obj.signatures)
            for obj in dispatchers()}

cold = signatures()
warm_kernels()
warm = signatures()
for parameters in json.loads(sys.argv[1]):
    Simulation(Model(n=64, box=8.0, **parameters), backend="cpu").run(2)
print(json.dumps({"cold": cold, "warm": warm, "after": signatures()}))
"""


def test_after_the_warm_up_no_setting_of_the_page_compiles():
    result = subprocess.run([sys.executable, "-c", PROBE, json.dumps(PAGE)], env={**os.environ, "PYTHONPATH": SRC},
                            capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stderr
    counts = json.loads(result.stdout.strip().splitlines()[-1])
    # the warm-up made kernels ready (it would have compiled them on a fresh install) ...
    assert sum(counts["warm"].values()) > sum(counts["cold"].values())
    # ... and every setting of the page then runs on them: no function gained a compiled version
    grew = {name: n - counts["warm"].get(name, 0) for name, n in counts["after"].items()
            if n != counts["warm"].get(name, 0)}
    assert grew == {}


def test_the_warm_up_covers_each_feature_of_the_page_and_plain_and_extended_kernels():
    from flocking.backends.cpu import kernel_name
    from flocking.backends.cpu_kernels import variant
    from flocking.backends.features import features

    kinds = {(m.dim, kernel_name(m), variant(features(m), kernel_name(m))) for m in server.warm_models()}
    assert {(f.extended, f.weighted, f.cohesion) for d, k, f in kinds if (d, k) == (2, "lines")} == \
        {(False, False, False), (True, False, False), (True, True, False), (True, True, True)}
    assert {(d, k, f.extended) for d, k, f in kinds} == {(2, "lines", False), (2, "lines", True), (2, "search", False),
                                                         (2, "search", True), (3, "lines", False), (3, "lines", True)}


def test_the_app_warms_up_once_per_process_in_a_background_thread():
    thread = server.start_warming()
    assert thread.daemon and thread.name == "flocking-play-warm-up"
    server.create_app(Model(n=50, box=8.0))
    assert server.start_warming() is thread
    thread.join(timeout=600)
    assert not thread.is_alive()
