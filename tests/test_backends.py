"""The step contract: reference == cpu to rounding for every option, exact properties,
and statistics with tolerances derived from theory."""

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

import flocking

from flocking import Model, Simulation, State
from flocking.backends.cpu import CPUBackend
from flocking.backends.reference import ReferenceBackend
from threads import results_by_threads

OPTIONS = {
    "vicsek": {},
    "vectorial": dict(noise_type="vectorial", noise=0.4),
    "alignment": dict(alignment=0.35),
    "delay": dict(delay=3),
    "forward": dict(update="forward"),
    "uniform-speeds": dict(speeds="uniform", dt=0.7),
    "topological": dict(neighbours="topological"),
    "topological-delay": dict(neighbours="topological", k=3, delay=2, noise_type="vectorial", noise=0.2),
    "rectangular": dict(box=(7.0, 3.2)),
    "box-below-3R": dict(box=2.5, radius=1.0),
    "box-below-R": dict(box=(0.8, 1.9), radius=1.0),
    "tiny-radius": dict(radius=0.05),
    "few-for-k": dict(n=5, box=3.0, neighbours="topological", k=7),
    "dense": dict(n=600, box=3.0, radius=0.9),
    "everything": dict(alignment=0.6, delay=2, update="forward", speeds="uniform", noise_type="vectorial",
                       noise=0.7, box=(6.0, 5.0)),
}


def make(dim, options):
    kw = dict(dim=dim, n=300, box=6.0 if dim == 2 else 4.0, noise=1.0, seed=4)
    kw.update(options)
    if dim == 3 and isinstance(kw["box"], tuple):
        kw["box"] = kw["box"] + (kw["box"][0] * 0.8,)
    return Model(**kw)


def assert_same_state(a, b, box, tol=1e-12):
    d = a.positions - b.positions
    d -= np.asarray(box) * np.round(d / np.asarray(box))
    assert np.abs(d).max() < tol
    assert np.abs(a.headings - b.headings).max() < tol
    assert a.step == b.step


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("name", OPTIONS)
def test_cpu_matches_reference_step_by_step(dim, name):
    model = make(dim, OPTIONS[name])
    ref = ReferenceBackend(model, State.random(model))
    cpu = CPUBackend(model, State.random(model))
    for _ in range(6):
        phi_ref, phi_cpu = ref.advance(1), cpu.advance(1)
        assert abs(phi_ref[0] - phi_cpu[0]) < 1e-12
        assert_same_state(ref.state, cpu.state, model.box)
        if not model.delay:  # restart from the oracle's state: compare single steps, not chaos
            cpu = CPUBackend(model, ref.state)


@pytest.mark.parametrize("dim", [2, 3])
def test_defaults_are_bitwise_the_same_as_explicit_delay_0_alignment_1(dim):
    a = Simulation(Model(dim=dim, n=500, box=7.0, seed=1))
    b = Simulation(Model(dim=dim, n=500, box=7.0, seed=1, delay=0, alignment=1.0))
    a.run(30)
    b.run(30)
    assert np.array_equal(a.state.positions, b.state.positions)
    assert np.array_equal(a.state.headings, b.state.headings)


SRC = os.path.dirname(os.path.dirname(flocking.__file__))  # this checkout's src/, for subprocesses

THREADS_SCRIPT = """
import sys, numpy as np, flocking
out = []
for kw in (dict(dim=2, noise=1.5), dict(dim=3, neighbours="topological", delay=2, noise=1.5),
           dict(dim=2, noise_type="vectorial", noise=0.3)):
    sim = flocking.Simulation(flocking.Model(n=3000, density=2.0, seed=9, **kw))
    sim.run(40)
    s = sim.state
    out.append(np.concatenate([s.positions.ravel(), s.headings.ravel(), np.array(sim.polar_order)]))
np.save(sys.argv[1], np.concatenate(out))
"""


def test_bitwise_identical_for_any_thread_count(tmp_path):
    results = results_by_threads(THREADS_SCRIPT, tmp_path)
    assert np.array_equal(results[0], results[1])


# -- exact properties ------------------------------------------------------------------


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("update", ["backward", "forward"])
def test_constant_speed_unit_headings_and_periodic_wrap(backend, dim, update):
    model = Model(dim=dim, n=200, box=(5.0, 4.0, 3.0)[:dim], speed=0.7, dt=0.5, noise=2.0, update=update,
                  speeds="uniform", seed=3)
    sim = Simulation(model, backend=backend)
    before = sim.state
    sim.run(1)
    after = sim.state
    assert after.n == before.n
    box = np.asarray(model.box)
    assert np.all(after.positions >= 0) and np.all(after.positions < box)
    assert np.allclose(np.linalg.norm(after.headings, axis=1), 1.0, atol=1e-14)
    moved = after.positions - before.positions
    moved -= box * np.round(moved / box)
    along = after.headings if update == "backward" else before.headings
    assert np.allclose(moved, (before.speeds * model.dt)[:, None] * along, atol=1e-12)
    assert np.array_equal(after.speeds, before.speeds)
    assert np.all(before.speeds > 0) and np.all(before.speeds <= model.speed)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("dim", [2, 3])
def test_box_smaller_than_radius_aligns_everyone_in_one_step(backend, dim):
    # every particle sees every other exactly once: all get the same mean heading
    model = Model(dim=dim, n=40, box=0.9, radius=1.0, noise=0.0, seed=2)
    sim = Simulation(model, backend=backend)
    mean = sim.state.headings.sum(axis=0)
    sim.run(1)
    h = sim.state.headings
    assert np.allclose(h, mean / np.linalg.norm(mean), atol=1e-13)
    assert sim.polar_order[-1] == pytest.approx(1.0, abs=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_no_alignment_and_no_noise_is_ballistic(dim):
    model = Model(dim=dim, n=300, box=5.0, alignment=0.0, noise=0.0, seed=5)
    sim = Simulation(model)
    h0 = sim.state.headings
    sim.run(10)
    assert np.allclose(sim.state.headings, h0, atol=1e-14)


def test_aligned_start_without_noise_stays_ordered():
    model = Model(n=1000, density=2.0, noise=0.0)
    sim = Simulation(model, State.aligned(model))
    sim.run(20)
    assert np.allclose(sim.state.headings, [1.0, 0.0])
    assert min(sim.polar_order) == 1.0


def test_topological_neighbours_ties_go_to_the_lower_index():
    # particle 0 at the centre, four others at the same distance: with k=2 the neighbours
    # are particles 1 and 2 (the lower indices), so 0 turns to the mean of 0, 1 and 2
    pos = np.array([[5.0, 5.0], [6.0, 5.0], [5.0, 6.0], [4.0, 5.0], [5.0, 4.0]])
    head = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [0.0, -1.0], [0.0, -1.0]])
    model = Model(n=5, box=10.0, neighbours="topological", k=2, noise=0.0)
    state = State(pos, head, np.full(5, 0.5))
    for backend in (ReferenceBackend, CPUBackend):
        b = backend(model, state)
        b.advance(1)
        expected = np.array([1.0, 2.0]) / math.sqrt(5.0)
        assert np.allclose(b.state.headings[0], expected, atol=1e-14)


def test_delay_sees_neighbours_as_they_were():
    # two particles within range; with delay 1, particle 0 at step 1 sees particle 1's
    # heading of step 0 (not its current one)
    pos = np.array([[1.0, 1.0], [1.5, 1.0]])
    head = np.array([[1.0, 0.0], [0.0, 1.0]])
    model = Model(n=2, box=10.0, delay=1, noise=0.0, speed=0.01)
    for backend in (ReferenceBackend, CPUBackend):
        b = backend(model, State(pos, head, np.full(2, 0.01)))
        b.advance(1)
        h1 = b.state.headings  # both turned to the mean (1, 1)/sqrt2: initial state stands in
        assert np.allclose(h1, [[2**-0.5, 2**-0.5]] * 2, atol=1e-14)
        b.advance(1)
        # step 1: own heading (1,1)/sqrt2 + the other's step-0 heading
        h = b.state.headings
        s0 = np.array([2**-0.5, 2**-0.5]) + np.array([0.0, 1.0])
        s1 = np.array([2**-0.5, 2**-0.5]) + np.array([1.0, 0.0])
        assert np.allclose(h[0], s0 / np.linalg.norm(s0), atol=1e-14)
        assert np.allclose(h[1], s1 / np.linalg.norm(s1), atol=1e-14)


# -- statistics with tolerances from theory ---------------------------------------------


def _single_particle_turns(dim, noise, noise_type, steps=4000):
    model = Model(dim=dim, n=1, box=50.0, noise=noise, noise_type=noise_type, seed=12)
    b = CPUBackend(model, State.random(model))
    before = [b.state.headings[0]]
    for _ in range(steps):
        b.advance(1)
        before.append(b.state.headings[0])
    return np.array(before)


@pytest.mark.parametrize("eta", [0.5, 2.0, 2 * math.pi])
def test_single_particle_angular_noise_kernel_2d(eta):
    h = _single_particle_turns(2, eta, "angular")
    turn = np.angle((h[1:, 0] + 1j * h[1:, 1]) / (h[:-1, 0] + 1j * h[:-1, 1]))
    # uniform on [-eta/2, eta/2]; KS at the 1e-4 level
    assert stats.kstest(turn, stats.uniform(-eta / 2, eta).cdf).pvalue > 1e-4


@pytest.mark.parametrize("eta", [1.0, 4.0])
def test_single_particle_angular_noise_kernel_3d(eta):
    h = _single_particle_turns(3, eta, "angular")
    cos_b = np.sum(h[1:] * h[:-1], axis=1)
    # uniform in area on the cap: cos(beta) uniform on [cos(eta/2), 1]
    lo = math.cos(eta / 2)
    assert stats.kstest(cos_b, stats.uniform(lo, 1 - lo).cdf).pvalue > 1e-4


def test_single_particle_vectorial_noise_kernel_2d():
    # S = u + eta * xi with xi uniform on the circle: the turn angle a has the density of
    # the direction of (1 + eta cos t, eta sin t); compare the sample with t drawn directly
    eta = 0.8
    h = _single_particle_turns(2, eta, "vectorial")
    turn = np.angle((h[1:, 0] + 1j * h[1:, 1]) / (h[:-1, 0] + 1j * h[:-1, 1]))
    t = np.random.default_rng(0).uniform(0, 2 * np.pi, 200_000)
    expected = np.arctan2(eta * np.sin(t), 1 + eta * np.cos(t))
    assert stats.ks_2samp(turn, expected).pvalue > 1e-4


@pytest.mark.parametrize("dim", [2, 3])
def test_full_noise_gives_the_random_polar_order(dim):
    # eta = 2 pi: headings independent and uniform, so N phi^2 has mean 1 exactly;
    # phi^2 of successive steps are independent, and N phi^2 has variance 1 (2D, exponential)
    # or 2/3 (3D, chi^2_3 / 3): the mean over T steps is within 5 sigma
    n, steps = 2000, 400
    sim = Simulation(Model(dim=dim, n=n, density=2.0, noise=2 * math.pi, seed=8))
    sim.run(steps)
    x = n * np.array(sim.polar_order[1:]) ** 2
    sigma = math.sqrt((1.0 if dim == 2 else 2.0 / 3.0) / steps)
    assert abs(x.mean() - 1.0) < 5 * sigma


def test_low_noise_orders_high_noise_does_not():
    ordered = Simulation(Model(n=1000, density=2.0, noise=0.5, seed=1))
    ordered.run(300)
    disordered = Simulation(Model(n=1000, density=2.0, noise=6.0, seed=1))
    disordered.run(300)
    assert np.mean(ordered.polar_order[-50:]) > 0.9
    assert np.mean(disordered.polar_order[-50:]) < 0.15


@pytest.mark.parametrize("options", [dict(dim=2), dict(dim=3, neighbours="topological", delay=2),
                                     dict(dim=2, delay=3, noise_type="vectorial", noise=0.3)])
def test_restart_from_state_and_memory_is_bitwise_identical(options):
    # the sorted order is a pure function of the state: a backend rebuilt from a state (and
    # its delay memory) continues exactly as one that never stopped
    model = Model(n=2000, density=3.0, seed=6, **options)
    whole = CPUBackend(model, State.random(model))
    phi_whole = whole.advance(30)
    part = CPUBackend(model, State.random(model))
    phi = list(part.advance(10))
    for _ in range(4):
        part = CPUBackend(model, part.state, memory=part.memory())
        phi += list(part.advance(5))
    assert np.array_equal(phi_whole, np.array(phi))
    assert np.array_equal(whole.state.positions, part.state.positions)
    assert np.array_equal(whole.state.headings, part.state.headings)


def test_seeds_beyond_double_precision_stay_distinct():
    # seeds above 2**53 are not representable as doubles: the kernels take them as uint64
    runs = []
    for seed in (2**60, 2**60 + 1):
        model = Model(n=200, box=6.0, noise=2.0, seed=seed)
        ref, cpu = ReferenceBackend(model, State.random(model)), CPUBackend(model, State.random(model))
        ref.advance(1)
        cpu.advance(1)
        assert np.abs(ref.state.headings - cpu.state.headings).max() < 1e-12
        runs.append(cpu.state.headings)
    assert not np.allclose(runs[0], runs[1])


COMPILE_SCRIPT = """
import sys, numpy as np, flocking
out = []
for kw in (dict(dim=2, delay=2), dict(dim=3)):
    sim = flocking.Simulation(flocking.Model(n=4000, density=2.0, noise=1.0, seed=3, **kw))
    sim.run(40)
    out.append(np.array(sim.polar_order))
    out.append(sim.state.headings.ravel())
np.save(sys.argv[1], np.concatenate(out))
"""


@pytest.mark.slow  # a minute of compiling: in the slow stage, which CI runs on every change
def test_freshly_compiled_and_cached_kernels_give_the_same_bits(tmp_path):
    # kernels compiled in this process and kernels loaded from numba's cache must round
    # alike: a first run and a second run of the same seed are bitwise identical
    env = dict(os.environ, PYTHONPATH=SRC, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    results = []
    for attempt in ("compiled", "cached"):
        path = tmp_path / f"{attempt}.npy"
        subprocess.run([sys.executable, "-c", COMPILE_SCRIPT, str(path)], check=True, env=env)
        results.append(np.load(path))
    assert np.array_equal(results[0], results[1])


def test_vectoriser_setting_applies_even_if_numba_was_imported_first():
    code = "import numba, flocking; print(numba.config.SLP_VECTORIZE)"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_SLP_VECTORIZE"}
    env["PYTHONPATH"] = SRC
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
