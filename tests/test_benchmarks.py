"""The benchmark scripts that need a GPU still run: each is exercised on a tiny system under
numba's CUDA simulator (in a subprocess, since the simulator must be on before numba is
imported), so a change to the engine that breaks one is seen without a GPU."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

ANATOMY = r"""
import sys
import numpy as np
sys.path.insert(0, "benchmarks")
import cuda_anatomy
import flocking
from flocking.backends.cuda import Engine

model = flocking.Model(n=64, density=2.0, noise=1.0, seed=3, delay=2)
state = flocking.State.random(model)
# the launches of a step, made one by one, are the step that advance() takes
one, other = Engine([model], [state], graphs=False), Engine([model], [state], graphs=False)
names = [name for name, _ in one.launches()]
for _ in range(3):
    for _, launch in one.launches():
        launch()
other.advance(3)
a, b = one.states()[0], other.states()[0]
assert (a.positions == b.positions).all() and (a.headings == b.headings).all()
cuda_anatomy.STEPS, cuda_anatomy.REPEATS = 1, 1
cuda_anatomy.anatomy("tiny", one, steps=1)
print("NAMES", " ".join(names))
"""


@pytest.mark.slow
def test_cuda_anatomy_times_the_launches_that_make_a_step():
    """``Engine.launches`` (which ``benchmarks/cuda_anatomy.py`` times one by one) made in
    turn is bit for bit the step that ``advance`` takes, and the script reports each."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run([sys.executable, "-c", ANATOMY], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    names = next(line for line in out.stdout.splitlines() if line.startswith("NAMES")).split()[1:]
    assert names[:2] == ["step", "digits"] and names[-2:] == ["gather", "finish"]
    assert all(name.startswith("scatter") for name in names[2:-2]) and len(names) > 4
    report = next(line for line in out.stdout.splitlines() if line.startswith("tiny: M = 64"))
    assert "host launches" in report
