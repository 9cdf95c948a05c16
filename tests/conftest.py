import os
import subprocess
import sys

import numpy as np
import pytest

from flocking import Model, State


@pytest.fixture
def small_model():
    return Model(n=300, box=6.0, noise=1.0, seed=4)


def min_image(d, box):
    box = np.asarray(box, dtype=float)
    return d - box * np.round(d / box)


@pytest.fixture
def random_state():
    def make(model):
        return State.random(model)

    return make


def pytest_configure(config):
    """For a run of the whole suite (no paths given), compile the kernels first, two
    processes side by side (tests/warm_kernels.py); each test process then loads them
    from numba's cache. Skipped in pytest-xdist's workers: the controller did it."""
    if os.environ.get("PYTEST_XDIST_WORKER") or config.args_source != pytest.Config.ArgsSource.TESTPATHS:
        return
    script = os.path.join(os.path.dirname(__file__), "warm_kernels.py")
    env = dict(os.environ, PYTHONPATH=os.path.join(os.path.dirname(os.path.dirname(script)), "src"))
    procs = [subprocess.Popen([sys.executable, script, group], env=env) for group in ("plain", "extensions")]
    for proc in procs:
        proc.wait()  # a failure here only means the tests compile what they need themselves
