"""The geometry's promises, for every geometry the model accepts (docs/model.md, Walls and
Obstacles): no particle ever inside an obstacle, none beyond a wall, on every backend.

Hypothesis draws the geometry: 2D or 3D, walls on any axes, a rectangular box, metric or
topological neighbours, then the widest obstacles and the longest step the model accepts,
found by bisection on :class:`flocking.Model`'s own refusals (so the test follows the rules
as they are, whatever they become): up to two obstacles, each with a radius up to the
largest allowed (for a trial step) beside the walls, its own periodic images and the
obstacles before it, then a speed up to the largest those obstacles allow. The largest
values are drawn as often as all the others together. The default suite draws 2D
geometries, the slow tests 3D ones.

The check is independent of the engine's geometry: the distance to every periodic image of
every obstacle (shifts of -L, 0, +L along periodic axes), from the positions a backend
returns. Tolerance: a pushed-out particle lands at ``c + (2a - d) n`` with ``d < a``, strictly
outside in exact arithmetic, so only rounding can put it inside: each coordinate carries a
few roundings of at most half an ulp of the box side (the push, the wrap, the difference
taken here) and the norm a relative ``eps``; ``64 eps max(L)`` (1e-13 for the boxes here)
bounds them with room to spare, while a trapped particle sinks by a fraction of a step.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from flocking import Model, State
from flocking.backends import get
from flocking.model import ParameterError
from gpu_marks import gpu

TESTS = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(os.path.dirname(TESTS), "src")
STEPS = 25


def accepted(**kw) -> bool:
    try:
        Model(**kw)
    except ParameterError:
        return False
    return True


def largest(accepts, low: float, high: float) -> float | None:
    """The largest ``x`` in ``[low, high]`` that ``accepts`` (true on an interval that starts
    at ``low``), to the last bit; ``None`` if it refuses ``low`` itself."""
    if not accepts(low):
        return None
    if accepts(high):
        return high
    while True:
        mid = 0.5 * (low + high)
        if mid in (low, high):
            return low
        if accepts(mid):
            low = mid
        else:
            high = mid


def up_to(top: float):
    """A value in ``(0, top]``: ``top`` itself as often as the rest."""
    return st.one_of(st.just(1.0), st.floats(0.02, 1.0)).map(lambda f: f * top)


@st.composite
def geometries(draw, dims=(2, 3)) -> dict:
    """A model in one of ``dims`` dimensions with walls, obstacles and a step as long as
    they allow."""
    dim = draw(st.sampled_from(dims))
    walls = draw(st.lists(st.booleans(), min_size=dim, max_size=dim))
    box = tuple(draw(st.floats(3.0, 9.0)) for _ in range(dim))
    kw = dict(dim=dim, n=40 if dim == 2 else 60, box=box, seed=draw(st.integers(0, 2**31)),
              boundary=",".join("wall" if w else "periodic" for w in walls),
              neighbours=draw(st.sampled_from(["metric", "topological"])), k=3,
              noise=draw(st.sampled_from([0.0, 0.5, 2.0, 6.0])), speeds=draw(st.sampled_from(["constant", "uniform"])))
    # obstacles first, as wide as a trial step allows (a step of 5 % to 25 % of the smallest side) ...
    step = draw(st.floats(0.05, 0.25)) * min(box)
    obstacles = []
    for _ in range(draw(st.sampled_from([2, 1, 0]))):
        # centres anywhere along periodic axes, in the middle 60 % between walls (room for a radius)
        centre = [length * draw(st.floats(0.2, 0.8) if wall else st.floats(0.0, 1.0))
                  for length, wall in zip(box, walls)]

        def fits(radius, centre=centre):
            return accepted(**kw, speed=step, obstacles=obstacles + [{"centre": centre, "radius": radius}])

        smallest = np.nextafter(step, np.inf)  # a radius must be above one step (dt = 1)
        widest = largest(fits, smallest, max(box))
        if widest is not None:
            obstacles.append({"centre": centre, "radius": smallest + draw(up_to(widest - smallest))})
    kw["obstacles"] = obstacles
    # ... then the speed, up to the longest step the box, the walls and these obstacles allow
    kw["speed"] = draw(up_to(largest(lambda v: accepted(**kw, speed=v), 1e-3, max(box))))
    return kw


def broken_promises(model: Model, x: np.ndarray) -> list[str]:
    """What is wrong with positions ``x``: particles beyond a wall or outside ``[0, L)``
    along a periodic axis, or inside an obstacle (any periodic image)."""
    box, walls = np.asarray(model.box), np.asarray(model.walls)
    tol = 64 * np.finfo(float).eps * box.max()
    found = []
    out = np.where(walls, (x < 0) | (x > box), (x < 0) | (x >= box)).any(axis=1)
    if out.any():
        found.append(f"{out.sum()} particles outside the box, e.g. {x[out][0].tolist()}")
    shifts = list(itertools.product(*[(0.0,) if w else (-length, 0.0, length) for length, w in zip(box, walls)]))
    for i, ob in enumerate(model.obstacles):
        centres = np.asarray(ob.centre) + np.asarray(shifts)
        distance = np.linalg.norm(x[:, None, :] - centres[None, :, :], axis=2).min(axis=1)
        inside = distance < ob.radius - tol
        if inside.any():
            found.append(f"{inside.sum()} particles inside obstacle {i} (radius {ob.radius!r}), the deepest "
                         f"{ob.radius - distance.min():.3g} below its surface")
    return found


def run_and_check(kw: dict, backends, steps: int = STEPS) -> None:
    model = Model(**kw)
    start = State.random(model)
    assert not broken_promises(model, start.positions), "the random start"
    for name in backends:
        backend = get(name)(model, start)
        for t in range(1, steps + 1):
            backend.advance(1)
            broken = broken_promises(model, backend.state.positions)
            assert not broken, f"{name}, step {t}: {'; '.join(broken)} ({kw})"


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kw=geometries(dims=(2,)))
def test_no_particle_inside_an_obstacle_or_beyond_a_wall(kw):
    run_and_check(kw, ("reference", "cpu"))


# in 3D, its small boxes run the 3D search kernel with walls, a minute's compiling that no
# other default test needs (the 3D walls and obstacles meet the reference in test_extensions)
@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kw=geometries(dims=(3,)))
def test_no_particle_inside_an_obstacle_or_beyond_a_wall_in_3d(kw):
    run_and_check(kw, ("reference", "cpu"))


def test_the_largest_obstacle_beside_its_own_image_keeps_particles_out():
    """The trap of a too-wide obstacle (box 16, radius 7.9: its image 0.2 away, closer than
    a step of 0.5) is refused; the widest allowed one (radius 7.75) holds a straight runner
    heading into the image, and a noisy crowd, out of the disc."""
    with pytest.raises(ParameterError, match="obstacles: obstacle 0 must keep at least one step"):
        Model(n=1, box=16.0, obstacles=[{"centre": [8.0, 8.0], "radius": 7.9}])
    widest = largest(lambda r: accepted(n=1, box=16.0, obstacles=[{"centre": [8.0, 8.0], "radius": r}]), 1.0, 16.0)
    assert widest == 7.75  # (L - step) / 2
    runner = Model(n=1, box=16.0, noise=0.0, obstacles=[{"centre": [8.0, 8.0], "radius": widest}])
    crowd = Model(n=60, box=16.0, noise=1.0, seed=3, obstacles=[{"centre": [8.0, 8.0], "radius": widest}])
    for model in (runner, crowd):
        start = State.random(model)
        if model is runner:
            start = State(np.array([[15.95, 8.0]]), np.array([[1.0, 0.0]]), start.speeds)
        for name in ("reference", "cpu"):
            backend = get(name)(model, start)
            for t in range(200):
                backend.advance(1)
                assert not broken_promises(model, backend.state.positions), (name, t)


def test_obstacles_as_close_as_allowed_keep_a_crowd_out():
    """Two discs as close as the model allows (the second as wide as it may be: the gap is
    one step) and a noisy crowd of 200 for 150 steps: a particle pushed out of one disc
    near the gap never lands in the other (with touching discs, 16 of these steps had one)."""
    base = dict(n=200, box=12.0, noise=2.0, seed=4)
    first = {"centre": [4.0, 6.0], "radius": 1.5}
    widest = largest(lambda r: accepted(**base, obstacles=[first, {"centre": [8.0, 6.0], "radius": r}]), 0.6, 12.0)
    assert widest == 2.0  # 4 - 1.5 - r >= one step, 0.5
    model = Model(**base, obstacles=[first, {"centre": [8.0, 6.0], "radius": widest}])
    start = State.random(model)
    for name in ("reference", "cpu"):
        backend = get(name)(model, start)
        for t in range(150):
            backend.advance(1)
            assert not broken_promises(model, backend.state.positions), (name, t)


#: the same property on the cuda backend under numba's simulator, in a subprocess (the
#: simulator must be on before numba is imported); fewer examples and steps: a step of 60
#: particles takes about a second of CPU there
CUDA_SCRIPT = r"""
import sys
sys.path.insert(0, sys.argv[1])
from hypothesis import HealthCheck, given, settings
from test_geometry_promises import geometries, run_and_check

@settings(max_examples=int(sys.argv[2]), deadline=None, suppress_health_check=list(HealthCheck))
@given(kw=geometries())
def check(kw):
    run_and_check(kw, ("cuda",), steps=int(sys.argv[3]))

check()
print("ok")
"""


@pytest.mark.slow
def test_the_same_promises_on_the_simulated_cuda_backend():
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "PYTHONPATH": SRC}
    result = subprocess.run([sys.executable, "-c", CUDA_SCRIPT, TESTS, "8", "10"], env=env, capture_output=True,
                            text=True, timeout=1800)
    assert result.returncode == 0 and result.stdout.strip().endswith("ok"), result.stderr[-4000:]


@pytest.mark.gpu
@gpu
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kw=geometries())
def test_the_same_promises_on_a_gpu(kw):
    run_and_check(kw, ("cuda",))


def test_the_search_finds_the_documented_limits():
    """The bisection on the model's refusals lands on the rules of docs/model.md: a step at
    most the smallest periodic side and below half of each side with walls; an obstacle at
    most ``(L - step) / 2`` wide beside its periodic image, and one step from a wall."""
    assert largest(lambda v: accepted(n=10, box=(6.0, 9.0), speed=v), 1e-3, 9.0) == 6.0
    below = largest(lambda v: accepted(n=10, box=(6.0, 9.0), boundary="wall,periodic", speed=v), 1e-3, 9.0)
    assert below < 3.0 and below == np.nextafter(3.0, 0.0)
    near_wall = largest(lambda r: accepted(n=10, box=10.0, boundary="wall", speed=0.5,
                                           obstacles=[{"centre": [3.0, 5.0], "radius": r}]), 0.6, 10.0)
    assert near_wall == 2.5  # 3 - r >= 0.5
