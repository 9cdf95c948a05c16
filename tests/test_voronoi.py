"""Voronoi neighbours (``neighbours = "voronoi"``, docs/voronoi.md): answers built by hand for
both the CPU backend's triangulation and the reference's brute-force cells, the two against
each other on random states (2D, 3D, walls), the margin's test of "enough", a step of every
extension against the reference, thread counts, and every refusal in one line."""

from __future__ import annotations

import builtins
import math

import numpy as np
import pytest
from click.testing import CliRunner

from flocking import Model, State
from flocking.backends import delaunay, voronoi_cells
from flocking.backends.cpu import CPUBackend
from flocking.backends.reference import ReferenceBackend
from flocking.backends.reference_voronoi import voronoi_matrix
from flocking.cli import main
from flocking.config import RunConfig
from flocking.model import ParameterError, dumps_toml, loads_toml
from threads import results_by_threads



def cpu_matrix(points, box, walls):
    """The CPU backend's neighbours of ``points`` ``(n, d)`` as a matrix."""
    points = np.asarray(points, dtype=np.float64)
    found = delaunay.graph(np.ascontiguousarray(points.T), np.asarray(box, float), np.asarray(walls))
    return matrix(found, len(points))


def matrix(found, n):
    """Compressed rows as a matrix."""
    offsets, nbrs = found
    a = np.zeros((n, n), dtype=bool)
    for i in range(n):
        assert np.all(np.diff(nbrs[offsets[i]:offsets[i + 1]]) > 0)  # increasing, each once
        a[i, nbrs[offsets[i]:offsets[i + 1]]] = True
    return a


def cells_matrix(points, box, walls):
    """The CPU backend's neighbours by each particle's own cell (2D; in 3D, or where that
    method does not apply, the triangulation's, which the other cases test)."""
    points = np.asarray(points, dtype=np.float64)
    found = voronoi_cells.from_points(points, box, walls) if points.shape[1] == 2 else None
    return cpu_matrix(points, box, walls) if found is None else matrix(found, len(points))


def ref_matrix(points, box, walls):
    return voronoi_matrix(np.asarray(points, dtype=np.float64), box, walls)


BOTH = pytest.mark.parametrize("neighbours", [cpu_matrix, cells_matrix, ref_matrix], ids=["qhull", "cells", "reference"])


def lattice(shape, spacing=1.0):
    axes = [(np.arange(m) + 0.5) * spacing for m in shape]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(shape))


# -- answers by hand ------------------------------------------------------------------------


@BOTH
def test_square_lattice_has_the_four_sides_not_the_diagonals(neighbours):
    # co-circular fours: Qhull draws one diagonal of each square, whose Voronoi side has no length
    points = lattice((6, 5))
    a = neighbours(points, (6.0, 5.0), (False, False))
    d = points[None] - points[:, None]
    d -= np.array([6.0, 5.0]) * np.round(d / np.array([6.0, 5.0]))
    assert np.array_equal(a, np.isclose(np.sum(d * d, axis=2), 1.0))
    assert np.all(a.sum(axis=1) == 4)


@BOTH
def test_square_lattice_in_walls_has_four_three_or_two(neighbours):
    a = neighbours(lattice((4, 4)), (4.0, 4.0), (True, True))
    counts = a.sum(axis=1).reshape(4, 4)
    assert counts.tolist() == [[2, 3, 3, 2], [3, 4, 4, 3], [3, 4, 4, 3], [2, 3, 3, 2]]


@BOTH
def test_hexagonal_lattice_has_six_at_unit_distance(neighbours):
    rows, cols = 6, 6
    h = math.sqrt(3) / 2
    points = np.array([((c + 0.5 * (r % 2)), r * h) for r in range(rows) for c in range(cols)])
    box = np.array([cols, rows * h])
    a = neighbours(points, box, (False, False))
    d = points[None] - points[:, None]
    d -= box * np.round(d / box)
    assert np.array_equal(a, np.isclose(np.sum(d * d, axis=2), 1.0))
    assert np.all(a.sum(axis=1) == 6)


@BOTH
def test_cubic_lattice_has_six_faces(neighbours):
    a = neighbours(lattice((3, 3, 4)), (3.0, 3.0, 4.0), (False, False, False))
    assert np.all(a.sum(axis=1) == 6)


@BOTH
def test_points_on_a_circle_neighbour_only_the_next_ones(neighbours):
    # eight co-circular points in walls: the cells are wedges meeting at the centre
    m = 8
    t = 2 * np.pi * np.arange(m) / m
    points = 5.0 + 2.0 * np.stack([np.cos(t), np.sin(t)], axis=1)
    a = neighbours(points, (10.0, 10.0), (True, True))
    i = np.arange(m)
    expect = np.zeros((m, m), dtype=bool)
    expect[i, (i + 1) % m] = expect[i, (i - 1) % m] = True
    assert np.array_equal(a, expect)


@BOTH
@pytest.mark.parametrize("walls", [(False, False), (True, True), (True, False)])
def test_two_points_are_neighbours_and_one_has_none(neighbours, walls):
    assert neighbours([[1.0, 1.0], [3.0, 2.5]], (5.0, 4.0), walls).tolist() == [[False, True], [True, False]]
    assert neighbours([[1.0, 1.0]], (5.0, 4.0), walls).tolist() == [[False]]


@BOTH
def test_neighbour_across_the_periodic_side_but_not_across_a_wall(neighbours):
    # a and b 1 apart through the side x = 0, c in the middle of the box
    points = [[0.5, 5.0], [9.5, 5.0], [5.0, 5.2]]
    periodic = neighbours(points, (10.0, 10.0), (False, False))
    assert periodic[0, 1] and periodic[1, 0]
    walled = neighbours(points, (10.0, 10.0), (True, False))
    assert not walled[0, 1] and walled[0, 2] and walled[1, 2]


@BOTH
def test_coincident_particles_are_one_site(neighbours):
    points = np.array([[1.0, 1.0], [1.0, 1.0], [3.0, 1.2], [2.0, 3.0]])
    a = neighbours(points, (4.0, 4.0), (True, True))
    assert a[0, 1] and a[1, 0] and not a.diagonal().any()
    assert np.array_equal(a[0, 2:], a[1, 2:]) and np.array_equal(a[2:, 0], a[2:, 1])
    # the same as the site alone, shared
    alone = neighbours(points[1:], (4.0, 4.0), (True, True))
    assert np.array_equal(a[1:, 1:], alone)
    assert np.array_equal(neighbours(np.ones((3, 2)), (4.0, 4.0), (False, False)), ~np.eye(3, dtype=bool))


@BOTH
def test_fewer_than_d_plus_2_particles(neighbours):
    three = [[1.0, 1.0, 1.0], [2.0, 1.5, 1.0], [1.5, 2.5, 2.0]]
    assert np.array_equal(neighbours(three, (4.0, 4.0, 4.0), (True, True, True)), ~np.eye(3, dtype=bool))


@BOTH
def test_collinear_particles_in_walls_are_strips(neighbours):
    points = [[0.5, 2.0], [1.5, 2.0], [2.5, 2.0], [3.5, 2.0]]
    a = neighbours(points, (4.0, 4.0), (True, True))
    assert a.sum(axis=1).tolist() == [1, 2, 2, 1] and a[1, 2] and not a[0, 2]


# -- the two methods on random states ----------------------------------------------------------


@pytest.mark.parametrize("dim, n, walls", [(2, 60, (False, False)), (2, 40, (True, False)), (2, 40, (True, True)),
                                           (2, 5, (False, False)), (3, 16, (False, False, False)),
                                           (3, 16, (True, False, True))])
def test_cpu_and_reference_agree_on_random_states(dim, n, walls):
    rng = np.random.default_rng(n + dim)
    box = rng.uniform(2.0, 5.0, dim) if dim == 2 else np.array([2.6, 2.4, 2.5])  # 3D: the reference's cost grows fast
    points = rng.random((n, dim)) * box
    expect = ref_matrix(points, box, walls)
    assert np.array_equal(cpu_matrix(points, box, walls), expect)
    assert np.array_equal(cells_matrix(points, box, walls), expect)


@pytest.mark.parametrize("walls", [(False, False), (True, False), (True, True)])
@pytest.mark.parametrize("side", [0.4, 1.0])
def test_cut_cells_agree_with_the_reference(walls, side):
    # each particle's own cell, cut in rings of cells (in boxes large enough that no ring wraps)
    rng = np.random.default_rng(7)
    box = np.array([13.0, 11.0])
    points = rng.random((280, 2)) * box
    found = voronoi_cells.from_points(points, box, walls, side)
    assert found is not None and np.array_equal(matrix(found, len(points)), ref_matrix(points, box, walls))
    few = voronoi_cells.from_points(points[:4], box, walls, side)
    if not all(walls):  # a ring would wrap around the periodic box: left to the triangulation
        assert few is None
    else:
        assert np.array_equal(matrix(few, 4), ref_matrix(points[:4], box, walls))


def test_the_margin_grows_until_it_is_enough(monkeypatch):
    # a clump in a large periodic box: its outer triangles' circles reach far beyond the
    # first margin; started from a margin of almost nothing, the test widens it to the same answer
    rng = np.random.default_rng(5)
    points = np.concatenate([rng.random((30, 2)) * 2.0 + 1.0, [[8.0, 8.5]]])
    box = (10.0, 10.0)
    expect = ref_matrix(points, box, (False, False))
    grown = []
    real = delaunay.images

    def spy(sites, b, w, margin):
        grown.append(margin)
        return real(sites, b, w, margin)

    monkeypatch.setattr(delaunay, "images", spy)
    for first in (0.01, delaunay.FIRST_MARGIN, 50.0):
        grown.clear()
        monkeypatch.setattr(delaunay, "FIRST_MARGIN", first)
        assert np.array_equal(cpu_matrix(points, box, (False, False)), expect)
        if first < 1:
            assert len(grown) > 1 and grown == sorted(grown)


def test_a_particle_on_a_wall_does_not_crash():
    points = np.array([[0.0, 1.0], [1.0, 2.0], [2.5, 0.5], [3.0, 3.0]])
    a = cpu_matrix(points, (4.0, 4.0), (True, True))
    assert np.array_equal(a, a.T) and not a.diagonal().any() and a.any(axis=1).all()


# -- a step of every extension against the reference -----------------------------------------

STEPS = {
    "plain-2d": dict(dim=2, n=40, box=5.0),
    "vectorial-forward": dict(dim=2, n=40, box=5.0, noise_type="vectorial", noise=0.4, update="forward"),
    "walls-vision-cohesion-delay": dict(dim=2, n=40, box=5.0, boundary="wall,periodic", vision=2.0, cohesion=0.6,
                                        delay=2),
    "species-nematic-chirality-field-obstacle": dict(
        dim=2, n=40, box=6.0, species=[{"n": 16, "noise": 0.3}, {"n": 24, "alignment": 0.5}],
        coupling=[[1.0, -0.5], [0.5, 1.0]], alignment_rule="nematic", chirality=0.2, field=(1, 0),
        field_strength=0.3, obstacles=[{"centre": [3.0, 3.0], "radius": 0.8}], cohesion=0.3),
    "plain-3d": dict(dim=3, n=12, box=2.5),
}


#: cases whose ``graph`` kernel no test of the default suite needs otherwise (compiled for
#: the case alone: 20 to 72 s of the default suite's 2 cores): in the slow stage
SLOW_STEPS = {"walls-vision-cohesion-delay", "species-nematic-chirality-field-obstacle", "plain-3d"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_STEPS else n for n in STEPS])
def test_cpu_step_agrees_with_the_reference(name):
    model = Model(**{"neighbours": "voronoi", "noise": 0.7, "seed": 11, **STEPS[name]})
    state = State.random(model)
    cpu, ref = CPUBackend(model, state), ReferenceBackend(model, state)
    phi_cpu, phi_ref = cpu.advance(3), ref.advance(3)
    assert np.allclose(phi_cpu, phi_ref, rtol=0, atol=1e-12)
    a, b = cpu.state, ref.state
    assert np.abs(a.positions - b.positions).max() < 1e-12
    assert np.abs(a.headings - b.headings).max() < 1e-12


def test_voronoi_changes_the_step_and_topological_is_left_alone():
    base = dict(n=60, box=5.0, noise=0.5, seed=2)
    state = State.random(Model(**base))
    voronoi = CPUBackend(Model(neighbours="voronoi", **base), state)
    metric = CPUBackend(Model(**base), state)
    voronoi.advance(1), metric.advance(1)
    assert not np.array_equal(voronoi.state.headings, metric.state.headings)


THREADS_SCRIPT = """
import sys
import numpy as np
from flocking import Model, Simulation
sim = Simulation(Model(neighbours="voronoi", density=2.0, seed=4, noise=0.6, **{kw}))
sim.run(5)
np.save(sys.argv[1], np.concatenate([sim.state.positions.ravel(), sim.state.headings.ravel(), sim.polar_order]))
"""


#: the plain model, and (slow stage: a kernel of its own) walls, a cone and cohesion
@pytest.mark.parametrize("kw", [dict(dim=2, n=3000), pytest.param(
    dict(dim=2, n=600, boundary="wall", vision=2.0, cohesion=0.5), marks=pytest.mark.slow)], ids=["plain", "extended"])
def test_bitwise_identical_for_any_thread_count(tmp_path, kw):
    results = results_by_threads(THREADS_SCRIPT.replace("{kw}", repr(kw)), tmp_path)
    assert np.array_equal(results[0], results[1])


# -- the surfaces and the refusals -------------------------------------------------------------


def test_model_round_trip_and_words():
    model = Model(n=50, box=5.0, neighbours="voronoi", dim=3)
    assert Model.from_dict(loads_toml(dumps_toml(model.to_dict()))) == model
    assert "voronoi," in str(model) and "k=" not in str(model)


def test_cuda_is_refused_in_one_line_naming_cpu():
    model = Model(n=50, box=5.0, neighbours="voronoi")
    with pytest.raises(ParameterError, match=r"^neighbours: the cuda backend has no 'voronoi' neighbours: use 'cpu'$"):
        RunConfig(model=model, backend="cuda")
    from flocking.backends.cuda import check_supported

    with pytest.raises(ParameterError, match="use 'cpu'"):
        check_supported([model])


def test_cli_runs_voronoi_and_refuses_cuda_before_writing(tmp_path):
    out = tmp_path / "r"
    result = CliRunner().invoke(main, ["run", "--neighbours", "voronoi", "--n", "200", "--steps", "3", "--quiet",
                                       "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert 'neighbours = "voronoi"' in (out / "config.toml").read_text()
    bad = tmp_path / "b"
    result = CliRunner().invoke(main, ["run", "--neighbours", "voronoi", "--backend", "cuda", "--out", str(bad)])
    assert result.exit_code == 2 and len(result.output.splitlines()) == 1
    assert "use 'cpu'" in result.output and not bad.exists()


def test_without_scipy_the_cpu_backend_refuses_in_one_line(monkeypatch):
    real = builtins.__import__

    def no_scipy(name, *args, **kwargs):
        if name.startswith("scipy"):
            raise ImportError("No module named 'scipy'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_scipy)
    model = Model(n=50, box=5.0, neighbours="voronoi")
    with pytest.raises(ParameterError, match=r"^neighbours: 'voronoi' on the cpu backend needs scipy"):
        RunConfig(model=model)
    with pytest.raises(ParameterError, match="needs scipy"):
        CPUBackend(model, State.random(model))
