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


# -- fields of any finite, non-zero length -------------------------------------------------------

#: a component: 0, or +-10^e with e anywhere from -300 to 300
component = st.one_of(st.just(0.0), st.builds(lambda sign, e: sign * 10.0**e, st.sampled_from([1.0, -1.0]),
                                               st.floats(-300.0, 300.0)))


def exact_direction(g) -> np.ndarray:
    """``g / |g|`` in 60-digit decimal arithmetic (every float converts exactly), rounded once."""
    from decimal import Decimal, localcontext

    with localcontext() as ctx:
        ctx.prec = 60
        exact = [Decimal(x) for x in g]
        norm = sum(x * x for x in exact).sqrt()
        return np.array([float(x / norm) for x in exact])


@settings(max_examples=300, deadline=None)
@given(g=st.one_of(st.tuples(component, component), st.tuples(component, component, component)))
def test_a_field_of_any_length_is_normalised_or_refused_in_one_line(g):
    try:
        model = flocking.Model(dim=len(g), n=10, box=4.0, field=list(g), field_strength=0.5)
    except ParameterError as err:
        assert not any(g)  # only the zero vector has no direction
        assert str(err).startswith("field: must be a direction: a non-zero vector") and "\n" not in str(err)
        return
    u = np.asarray(model.field_direction)
    assert abs(np.linalg.norm(u) - 1.0) < 4 * np.finfo(float).eps
    np.testing.assert_allclose(u, exact_direction(g), rtol=0, atol=4 * np.finfo(float).eps)


#: fields at the ends of the range, mixed signs, in 2D and 3D, and their directions
EXTREME_FIELDS = [((1e-300, -1e-300), (2**-0.5, -(2**-0.5))), ((-1e300, 1e300), (-(2**-0.5), 2**-0.5)),
                  ((1e300, -1e-300), (1.0, -0.0)), ((-1e-300, 0.0, 1e-300), (-(2**-0.5), 0.0, 2**-0.5)),
                  ((1e-300, 1e300, -1e300), (0.0, 2**-0.5, -(2**-0.5)))]


@pytest.mark.parametrize("backend", ["reference", "cpu"])
@pytest.mark.parametrize("g, direction", EXTREME_FIELDS)
def test_a_run_in_an_extreme_field_follows_it(backend, g, direction):
    """The strongest field (h = 1000) without noise turns every heading to g in one step:
    ``S_i + h n_i g`` is g within ``|S_i| / (h n_i) <= 1e-3``."""
    model = flocking.Model(dim=len(g), n=50, box=5.0, noise=0.0, field=list(g), field_strength=1000.0, seed=1)
    sim = flocking.Simulation(model, backend=backend)
    sim.run(3)
    headings = sim.state.headings
    assert np.isfinite(sim.state.positions).all() and np.isfinite(sim.polar_order).all()
    assert np.abs(headings - np.asarray(direction)).max() < 1e-3


def test_cli_runs_in_a_field_of_length_1e_170(tmp_path):
    """A field whose squared length underflows to 0 (it crashed the run with a ZeroDivisionError)."""
    out = tmp_path / "X"
    result = subprocess.run([sys.executable, "-m", "flocking", "run", "--n", "100", "--box", "16", "--steps", "1",
                             "--field", "1e-170,1e-170", "--field-strength", "0.5", "--out", str(out)],
                            env={**os.environ, "PYTHONPATH": SRC}, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, describe(result)
    rows = (out / "observables.csv").read_text().splitlines()
    assert rows[0] == "step,polar_order" and len(rows) == 3


@pytest.mark.parametrize("species", ['[{n = 0}, {n = 100}]', '[{fraction = 0.001}, {fraction = 0.999}]'])
def test_cli_refuses_an_empty_species_in_one_line(tmp_path, species):
    config = tmp_path / "c.toml"
    config.write_text(f"box = 10.0\nspecies = {species}\n" + ("n = 100\n" if "fraction" in species else ""))
    out = tmp_path / "X"
    result = subprocess.run([sys.executable, "-m", "flocking", "run", "--config", str(config), "--steps", "2",
                             "--out", str(out)], env={**os.environ, "PYTHONPATH": SRC}, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 2, describe(result)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: species: every species must hold at least one particle")
    assert not out.exists()
