"""No value crashes the process: extreme parameters are refused in one line or run, and the
kernels stay in bounds whatever the state holds (NaN, infinities, 1e300).

The runs happen in a subprocess, so that a segmentation fault is reported as a failing
test (with the signal's name) instead of killing the test session.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import flocking
from flocking.model import ParameterError

SRC = os.path.dirname(os.path.dirname(flocking.__file__))

#: Runs models at the edges of what validation accepts, then states no model produces.
SCRIPT = r"""
import sys
import numpy as np
import flocking
from flocking.backends import get

backend = get(sys.argv[1])
small = sys.argv[1] == "reference"

def models():
    for dim in (2, 3):
        n = 60 if small else 600
        box = 6.0
        yield dict(dim=dim, n=n, box=box, speed=box)                  # the longest step allowed
        yield dict(dim=dim, n=n, box=box, speed=1e-300, dt=1e-300)    # vanishing steps
        yield dict(dim=dim, n=n, box=box, radius=1e-300)              # cells capped at ~N
        yield dict(dim=dim, n=n, box=box, radius=1e150)               # everyone sees everyone
        yield dict(dim=dim, n=n, box=box, noise_type="vectorial", noise=1000.0)
        yield dict(dim=dim, n=n, box=(1e-3,) + (1e6,) * (dim - 1), speed=5e-4)  # a needle of a box
        yield dict(dim=dim, n=1, box=1e-100, speed=1e-101)
        yield dict(dim=dim, n=2, box=box, neighbours="topological", k=1000, delay=3)
        yield dict(dim=dim, n=n, density=1e-6, neighbours="topological", k=3)

for kw in models():
    model = flocking.Model(seed=1, **kw)
    phi = backend(model, flocking.State.random(model)).advance(3)
    assert np.isfinite(phi).all() and (phi <= 1 + 1e-9).all(), (kw, phi)

bad_values = (np.nan, np.inf, -np.inf, 1e300, -1e300, 1e20, -5.0, 6.0)
for dim in (2, 3):
    for neighbours in ("metric", "topological"):
        for box in (6.0, 2.5):  # the fast path and the generic one (a box below 3R)
            model = flocking.Model(dim=dim, n=60 if small else 500, box=box, neighbours=neighbours, k=4,
                                   delay=1, seed=2)
            start = flocking.State.random(model)
            for bad in bad_values:
                state = start.copy()
                state.positions[::7, 0] = bad
                state.positions[3::11, dim - 1] = -bad
                state.headings[::5, 1] = bad
                state.headings[2::9] = 0.0
                backend(model, state).advance(2)  # any result, as long as nothing breaks
print("ok")
"""


def run_script(backend: str, env: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC, **(env or {})}
    return subprocess.run([sys.executable, "-c", SCRIPT, backend], env=env, capture_output=True, text=True,
                          timeout=600)


def describe(result: subprocess.CompletedProcess) -> str:
    if result.returncode < 0:
        return f"killed by {signal.Signals(-result.returncode).name}\n{result.stderr[-3000:]}"
    return result.stderr[-3000:]


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_extreme_models_and_states_never_crash(backend):
    result = run_script(backend)
    assert result.returncode == 0, describe(result)
    assert result.stdout.strip() == "ok"


@pytest.mark.parametrize("args, option", [
    (["--speed", "1e20", "--n", "40000"], "--speed"),
    (["--speed", "1e300", "--dt", "1e300"], "--speed"),
    (["--noise-type", "vectorial", "--noise", "1e308"], "--noise"),
    (["--box", "1e-200", "--n", "5"], "--box"),
])
def test_cli_refuses_overflowing_values_in_one_line(tmp_path, args, option):
    env = {**os.environ, "PYTHONPATH": SRC}
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "flocking", "run", *args, "--steps", "5", "--out", str(out)],
                            env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, describe(result)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {option}:"), result.stderr
    assert not out.exists()


finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(
    [0.0, -0.0, 5e-324, 1e-300, 1e-10, 1.0, 1e10, 1e150, 1e300, 1.7976931348623157e308]))


@settings(max_examples=400, deadline=None)
@given(speed=finite_or_not, dt=finite_or_not, box=finite_or_not, radius=finite_or_not, noise=finite_or_not,
       vectorial=st.booleans(), dim=st.sampled_from([2, 3]))
def test_every_accepted_model_has_finite_bounded_steps(speed, dt, box, radius, noise, vectorial, dim):
    """What validation accepts cannot overflow in a step: the step is at most a box side,
    and every term of a sum of headings (``eta * n_i`` included) is finite."""
    try:
        model = flocking.Model(dim=dim, n=100, box=box, speed=speed, dt=dt, radius=radius, noise=noise,
                               noise_type="vectorial" if vectorial else "angular")
    except ParameterError as err:
        assert "\n" not in str(err) and ": must be" in str(err)
        return
    assert math.isfinite(model.speed * model.dt) and model.speed * model.dt <= min(model.box)
    assert math.isfinite(model.radius**2)
    assert math.isfinite(model.noise * model.n * 4)
    assert np.isfinite(np.prod(model.box))


def test_a_non_finite_state_is_refused_and_a_run_that_turns_non_finite_stops(tmp_path):
    model = flocking.Model(n=200, box=10.0, seed=3)
    state = flocking.State.random(model)
    state.positions[5, 0] = np.nan
    with pytest.raises(ParameterError, match=r"^state: positions and headings must be finite \(1 particles"):
        flocking.Simulation(model, state)
    # headings far from unit length overflow the sum of headings at the first step
    state = flocking.State.random(model)
    state.headings[:] = 1e300
    sim = flocking.Simulation(model, state)
    csv = tmp_path / "observables.csv"
    sim.writers.append(flocking.ObservablesWriter(csv))
    with pytest.raises(flocking.NonFiniteError, match=r"^the run became non-finite at step 1 \(polar order nan\)"):
        sim.run(10)
    rows = csv.read_text().splitlines()
    assert rows[0] == "step,polar_order" and len(rows) == 2 and rows[1].startswith("0,")  # no nan row
