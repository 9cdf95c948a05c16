"""The CPU kernels against the reference backend, option by option, and thread-count
independence of whole runs.

From the same state one cpu step must equal one reference step to rounding; every option
of the model goes through a different branch of the kernels (fast 2D/3D metric path,
generic path for boxes under 3R, topological search, delay ring, ...).
"""

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from flocking import Model, State
from flocking.backends.cells import cell_grid
from flocking.backends.cpu import CPUBackend, kernel_name
from flocking.backends.reference import ReferenceBackend

TOL = 1e-12

CASES = {
    "2d": dict(n=300, box=12.0),
    "3d": dict(dim=3, n=300, box=6.0),
    "forward": dict(n=300, box=12.0, update="forward"),
    "vectorial": dict(n=300, box=12.0, noise_type="vectorial", noise=0.8),
    "vectorial-3d": dict(dim=3, n=250, box=6.0, noise_type="vectorial", noise=0.8),
    "alignment": dict(n=300, box=12.0, alignment=0.3),
    "alignment-3d": dict(dim=3, n=250, box=6.0, alignment=0.6),
    "uniform-speeds": dict(n=300, box=12.0, speeds="uniform", speed=1.3),
    "rectangle": dict(n=300, box=(20.0, 7.5)),
    "box-3d": dict(dim=3, n=300, box=(8.0, 5.0, 4.0)),
    # three cells a side, the fewest of the fast path: every line wraps at both ends
    "three-cells": dict(n=60, box=3.2),
    "three-cells-3d": dict(dim=3, n=80, box=(3.3, 3.1, 4.5)),
    # lines of more than one work segment (64 columns of cells)
    "long-2d": dict(n=3000, box=(150.0, 10.0)),
    "long-3d": dict(dim=3, n=2000, box=(140.0, 4.0, 3.5)),
    "small-box": dict(n=200, box=(2.5, 9.0), radius=1.0),
    "tiny-box-3d": dict(dim=3, n=200, box=2.0, radius=1.2),
    "huge-radius": dict(n=200, box=4.0, radius=3.5),
    "tiny-radius": dict(n=300, box=12.0, radius=1e-3),
    "big-radius": dict(n=300, box=30.0, radius=2.7),
    "topological": dict(n=300, box=12.0, neighbours="topological", k=7),
    "topological-3d": dict(dim=3, n=300, box=6.0, neighbours="topological", k=5),
    "topological-few": dict(n=6, box=3.0, neighbours="topological", k=7),
    "topological-rect": dict(n=300, box=(40.0, 3.0), neighbours="topological", k=3),
    "delay": dict(n=300, box=12.0, delay=3),
    "delay-3d-vectorial": dict(dim=3, n=250, box=6.0, delay=2, noise_type="vectorial"),
    "delay-topological": dict(n=300, box=12.0, delay=2, neighbours="topological"),
    "dt": dict(n=300, box=12.0, dt=0.3, speed=2.0),
}


def assert_same(a: State, b: State, box, tol: float = TOL) -> None:
    assert a.step == b.step
    np.testing.assert_allclose(a.headings, b.headings, rtol=0, atol=tol)
    # the same point up to a whole box side along each axis: a wrap at the edge, nothing else
    gap = a.positions - b.positions
    gap -= np.asarray(box) * np.round(gap / np.asarray(box))
    assert np.abs(gap).max() < tol, "positions differ"
    np.testing.assert_array_equal(a.speeds, b.speeds)


@pytest.mark.parametrize("name", sorted(CASES))
def test_each_step_matches_reference(name):
    """Five steps from the same states: every step agrees to rounding, phi too."""
    model = Model(seed=11, **{"noise": 0.6, **CASES[name]})
    state = State.random(model)
    cpu, ref = CPUBackend(model, state), ReferenceBackend(model, state)
    for _ in range(5):
        phi_cpu, phi_ref = cpu.advance(1), ref.advance(1)
        np.testing.assert_allclose(phi_cpu, phi_ref, rtol=0, atol=1e-12)
        assert_same(cpu.state, ref.state, model.box)
        if model.delay == 0:
            # restart both from the reference state, so rounding never accumulates
            cpu = CPUBackend(model, ref.state)


def test_neighbour_sums_and_ring_layout():
    """``ring[t % delay, id] = (sum of neighbours' headings without self, 1 + count)``."""
    model = Model(n=300, box=12.0, noise=0.4, delay=3, seed=5)
    state = State.random(model)
    cpu = CPUBackend(model, state)
    from flocking.backends.reference import neighbour_matrix

    a = neighbour_matrix(model, state.positions)
    np.fill_diagonal(a, False)
    expect = np.concatenate([a @ state.headings, 1.0 + a.sum(axis=1)[:, None]], axis=1)
    np.testing.assert_allclose(cpu.neighbour_sums(), expect, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cpu._ring, np.repeat(expect[None], 3, axis=0), rtol=0, atol=1e-12)
    cpu.advance(1)
    np.testing.assert_allclose(cpu._ring[0], expect, rtol=0, atol=1e-12)  # step 0 wrote slot 0
    assert cpu._step_count == 1


def test_clustered_dense_state_matches_reference():
    """Half the particles packed in one cell-sized blob: long ranges, many neighbours."""
    model = Model(n=400, box=15.0, noise=0.3, seed=3)
    state = State.random(model)
    blob = np.random.default_rng(0).uniform(0.0, 1.5, size=(200, 2)) + 14.0
    state.positions[:200] = np.mod(blob, 15.0)
    cpu, ref = CPUBackend(model, state), ReferenceBackend(model, state)
    for _ in range(3):
        cpu.advance(1)
        ref.advance(1)
        assert_same(cpu.state, ref.state, model.box)
        cpu = CPUBackend(model, ref.state)


@pytest.mark.parametrize("dim", [2, 3])
def test_crowded_lines_grow_the_buffer_and_match_reference(dim):
    """Thousands of particles within one cell: the kernel's candidate buffer (4096
    entries to start with) must grow, and every sum still matches."""
    model = Model(n=4600, dim=dim, box=10.0 if dim == 2 else 5.0, noise=0.3, seed=8)
    state = State.random(model)
    state.positions[:4400] = np.random.default_rng(1).uniform(2.0, 2.9, size=(4400, dim))
    cpu, ref = CPUBackend(model, state), ReferenceBackend(model, state)
    np.testing.assert_allclose(cpu.advance(1), ref.advance(1), rtol=0, atol=1e-12)
    assert_same(cpu.state, ref.state, model.box)


def test_cell_grid_is_capped():
    assert cell_grid(Model(n=100, box=1000.0, radius=1e-6, noise=0.1)).prod() <= 100
    assert cell_grid(Model(n=100, box=(2.0, 50.0), noise=0.1)).tolist()[0] == 1
    assert cell_grid(Model(n=10**4, box=100.0, noise=0.1)).tolist() == [99, 99]


_RUN = textwrap.dedent("""
    import sys, numpy as np
    from flocking import Model, State
    from flocking.backends.cpu import CPUBackend
    out = []
    for kw in [dict(n=20000, density=2.0), dict(dim=3, n=6000, density=1.0),
               dict(n=5000, density=2.0, neighbours="topological", delay=2)]:
        model = Model(noise=0.5, seed=4, **kw)
        b = CPUBackend(model, State.random(model))
        phi = b.advance(12)
        s = b.state
        out.append(np.concatenate([phi, s.positions.ravel(), s.headings.ravel()]))
    np.save(sys.argv[1], np.concatenate(out))
""")


def test_bitwise_identical_for_one_and_two_threads(tmp_path):
    src = os.path.join(os.path.dirname(__file__), os.pardir, "src")
    results = []
    for threads in (1, 2):
        path = tmp_path / f"t{threads}.npy"
        env = {**os.environ, "NUMBA_NUM_THREADS": str(threads), "PYTHONPATH": os.path.abspath(src)}
        subprocess.run([sys.executable, "-c", _RUN, str(path)], check=True, env=env)
        results.append(np.load(path))
    assert results[0].tobytes() == results[1].tobytes()


def test_saved_order_is_restored_and_checked():
    """The order a checkpoint saves comes back slot for slot; a corrupt one is refused."""
    from flocking.model import ParameterError

    model = Model(n=500, box=15.0, noise=0.5, seed=2)
    cpu = CPUBackend(model, State.random(model))
    cpu.advance(7)  # particles have changed cells: the order is no longer by id within them
    memory = cpu.memory()
    again = CPUBackend(model, cpu.state, memory=memory)
    np.testing.assert_array_equal(again._ids, cpu._ids)
    np.testing.assert_array_equal(again.advance(3), cpu.advance(3))
    for bad in (memory["order"][:-1], np.zeros(500, dtype=np.int32), memory["order"] * 1.0):
        with pytest.raises(ParameterError, match="particle order"):
            CPUBackend(model, again.state, memory={"order": bad})


@pytest.mark.slow
@pytest.mark.parametrize("extension", [dict(vision=2.1, neighbours="topological", k=5),
                                       dict(alignment_rule="nematic", neighbours="topological", k=5),
                                       dict(species=[{"fraction": 0.5}, {"fraction": 0.5}],
                                            coupling=[[1.0, -0.5], [-0.5, 1.0]], box=2.6)],
                         ids=["vision-topological", "nematic-topological", "coupling-small-box"])
def test_the_shared_weighted_variant_gives_the_bits_of_a_variant_of_its_own(extension, monkeypatch):
    # in the search kernel cpu_kernels.variant compiles the pair weights (a coupling, nematic
    # signs, a cone) in together when any is on; those the model leaves off multiply by
    # exactly 1, so 20 steps equal those of the variant compiled for the model alone
    from flocking.backends import cpu_kernels

    model = Model(**{"n": 400, "box": 12.0, "noise": 0.4, "seed": 5, **extension})
    assert kernel_name(model) == "search"
    shared = CPUBackend(model, State.random(model))
    assert shared._kernel is getattr(cpu_kernels.build(cpu_kernels.variant(shared._features, kernel_name(model)), 2),
                                     shared._kernel.py_func.__name__.split("_")[0])
    monkeypatch.setattr(cpu_kernels, "variant", lambda features, kernel: features)
    own = CPUBackend(model, State.random(model))
    assert own._kernel is not shared._kernel
    assert np.array_equal(shared.advance(20), own.advance(20))
    assert np.array_equal(shared.state.positions, own.state.positions)
    assert np.array_equal(shared.state.headings, own.state.headings)


def test_noting_a_group_keeps_exactly_the_displacements_that_count_in_order():
    # cohesion's lanes note a group of four displacements through a compress: every mask,
    # after an earlier group, must leave near[row, :k] the values whose count is not 0, in
    # order, zeros after them in the group, and the earlier entries untouched
    from flocking.backends.cpu_kernels import note

    values = (0.25, -3.0, 7.5, -0.0)
    for mask in range(16):
        w = [float(mask >> lane & 1) for lane in range(4)]
        near = np.full((2, 12), 99.0)
        k = note(near, np.uint64(0), 1, 1.0, 2.0, 3.0, 4.0, 1.0, 0.0, 0.0, 1.0)
        k = note(near, k, 1, *values, *w)
        kept = [values[lane] for lane in range(4) if w[lane]]
        assert k == 2 + len(kept)
        assert near[1, :k].tolist() == [1.0, 4.0] + kept
        assert [math.copysign(1.0, v) for v in near[1, :k]] == [math.copysign(1.0, v) for v in [1.0, 4.0] + kept]
        assert near[1, k:6].tolist() == [0.0] * (6 - k)
        assert near[1, 6:].tolist() == [99.0] * 6 and near[0].tolist() == [99.0] * 12


@pytest.mark.parametrize("form", ["avx512", "avx2", "select"])
def test_every_form_of_the_compress_moves_the_chosen_values_to_the_front(form):
    # each machine code the module may choose, on whichever of them this machine runs
    # (tests/test_intrinsics.py compiles each for the targets it is chosen for)
    import numba

    from flocking.backends.intrinsics import COMPRESS, compress_intrinsic

    if form != "select" and COMPRESS not in (form, "avx512"):  # a machine with AVX-512 has AVX2
        pytest.skip(f"numba does not compile for a target with the {form} form here")
    compress = compress_intrinsic(form)

    @numba.njit
    def run(v, b):
        return compress(v[0], v[1], v[2], v[3], b[0], b[1], b[2], b[3])

    v = np.array([1.5, np.nan, -np.inf, 5e-324])
    for mask in range(16):
        b = np.array([bool(mask >> lane & 1) for lane in range(4)])
        got = np.array(run(v, b))
        want = np.zeros(4)
        want[:b.sum()] = v[b]
        assert np.array_equal(got, want, equal_nan=True), (mask, got)
