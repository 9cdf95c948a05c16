"""flocking.neighbour_query: the k nearest and the pairs within a distance against brute force
written from the definitions; cell lists built once; every refusal."""

import numba
import numpy as np
import pytest

from flocking.checks import ParameterError
from flocking.space import Space

WALLS = {"none": lambda d: [False] * d, "first": lambda d: [True] + [False] * (d - 1), "all": lambda d: [True] * d}


def brute_distances(points, box, walls):
    """All distances: ``d - L round(d / L)`` along periodic axes, the plain difference along walls."""
    points, box = np.asarray(points, float), np.asarray(box, float)
    d = points[None, :, :] - points[:, None, :]
    periodic = ~np.asarray(walls)
    d[..., periodic] -= box[periodic] * np.round(d[..., periodic] / box[periodic])
    return np.sqrt((d**2).sum(axis=2))


def brute_nearest(points, box, walls, k):
    r = brute_distances(points, box, walls)
    n = len(points)
    np.fill_diagonal(r, np.inf)
    index = np.broadcast_to(np.arange(n), (n, n))
    order = np.array([np.lexsort((index[i], r[i])) for i in range(n)])[:, :k]  # nearest, then the lower index
    return order, np.take_along_axis(r, order, axis=1)


def space_and_points(dim, walls, side, n, seed):
    rng = np.random.default_rng(seed)
    box = side * np.array([1.0, 0.8, 1.2][:dim])
    points = rng.uniform(0, 1, (n, dim)) * box
    return Space(tuple(box), tuple(WALLS[walls](dim))), points


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("walls", list(WALLS))
@pytest.mark.parametrize("side, n, k", [(10.0, 300, 6), (2.0, 40, 7), (10.0, 50, 49), (30.0, 200, 1)])
def test_nearest_matches_brute_force(dim, walls, side, n, k):
    # many cells, fewer than three cells per axis, k = N - 1, a sparse box
    space, points = space_and_points(dim, walls, side, n, seed=dim * 1000 + n + k)
    indices, distances = space.neighbours(points).nearest(k)
    expected_i, expected_d = brute_nearest(points, space.box, space.walls, k)
    np.testing.assert_array_equal(indices, expected_i)
    np.testing.assert_allclose(distances, expected_d, rtol=1e-12)


@pytest.mark.parametrize("walls", ["none", "first"])
def test_nearest_ties_go_to_the_lower_index(walls):
    # a square lattice, shuffled: every point has 4 others at exactly 1 and 4 at sqrt(2)
    grid = np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0), indexing="ij"), axis=-1).reshape(-1, 2) + 0.5
    points = grid[np.random.default_rng(3).permutation(len(grid))]
    space = Space((8.0, 8.0), walls=tuple(WALLS[walls](2)))
    indices, distances = space.neighbours(points).nearest(6)
    expected_i, expected_d = brute_nearest(points, space.box, space.walls, 6)
    np.testing.assert_array_equal(indices, expected_i)
    np.testing.assert_allclose(distances, expected_d, rtol=1e-12)
    if walls == "none":
        assert np.all(distances[:, :4] == 1.0)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("walls", list(WALLS))
def test_within_matches_brute_force(dim, walls):
    space, points = space_and_points(dim, walls, 6.0, 250, seed=dim + len(walls))
    pairs = space.neighbours(points).within(1.7)
    r = brute_distances(points, space.box, space.walls)
    i, j = np.nonzero(np.triu(r < 1.7, k=1))
    got = sorted(zip(pairs.i.tolist(), pairs.j.tolist()))
    assert got == sorted(zip(i.tolist(), j.tolist()))
    assert np.all(pairs.i < pairs.j)
    np.testing.assert_allclose(pairs.distance, r[pairs.i, pairs.j], rtol=1e-12)


def test_centred_coordinates_give_the_same_neighbours():
    corner, points = space_and_points(2, "first", 10.0, 200, seed=5)
    centred = corner.with_origin(-corner.lengths / 2)
    a, b = corner.neighbours(points).nearest(5), centred.neighbours(points - corner.lengths / 2).nearest(5)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)


def test_a_cell_list_is_built_once_per_cell_width():
    space, points = space_and_points(2, "none", 20.0, 400, seed=7)
    query = space.neighbours(points)
    assert query.cell_lists == 0
    first = query.within(1.5)
    counts, _ = query.pair_histogram(1.5, 6)
    list(query.pair_blocks(1.5, block=10))
    assert query.cell_lists == 1  # three questions at one distance: one cell list
    assert counts.sum() == len(first.i)
    query.within(4.0)
    assert query.cell_lists == 2  # wider cells for a longer distance
    query.within(1.5)
    assert query.cell_lists == 2


def test_the_pair_histogram_does_not_depend_on_the_thread_count():
    space, points = space_and_points(3, "first", 8.0, 3000, seed=11)
    vectors = np.random.default_rng(0).normal(size=(len(points), 3))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = space.neighbours(points).pair_histogram(2.0, 20, vectors)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = space.neighbours(points).pair_histogram(2.0, 20, vectors)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(one[0], many[0])
    np.testing.assert_array_equal(one[1], many[1])


@pytest.mark.parametrize("ask, message", [
    (lambda q: q.nearest(0), "k: must be a whole number >= 1 (got 0)"),
    (lambda q: q.nearest(5), "k: must be at most the number of other points, 4 (got 5)"),
    (lambda q: q.nearest(2.5), "k: must be a whole number >= 1 (got 2.5)"),
    (lambda q: q.nearest(True), "k: must be a whole number >= 1 (got True)"),
    (lambda q: q.within(0.0), "cutoff: must be a finite number > 0 (got 0.0)"),
    (lambda q: q.within(float("nan")), "cutoff: must be a finite number > 0 (got nan)"),
    (lambda q: q.pair_histogram(1.0, 0), "bins: must be a whole number >= 1 (got 0)"),
])
def test_refusals_name_the_parameter(ask, message):
    query = Space((4.0, 4.0)).neighbours(np.random.default_rng(1).uniform(0, 4, (5, 2)))
    with pytest.raises(ParameterError) as error:
        ask(query)
    assert str(error.value) == message
    assert query.cell_lists == 0


def test_points_must_match_the_space():
    with pytest.raises(ParameterError, match=r"points: must be rows of 2 coordinates \(got shape \(4, 3\)\)"):
        Space((4.0, 4.0)).neighbours(np.zeros((4, 3)))
    with pytest.raises(ParameterError, match="k: must be at most the number of other points, 0"):
        Space((4.0, 4.0)).neighbours(np.zeros((1, 2))).nearest(1)


@pytest.mark.parametrize("dim", [2, 3])
def test_cells_are_numbered_as_the_engine_numbers_them(dim):
    from flocking.backends.cells import cell_indices

    space, points = space_and_points(dim, "first", 9.0, 500, seed=dim)
    cl = space.neighbours(points).cells(1.0)
    slot_cell = np.repeat(np.arange(len(cl.start) - 1), np.diff(cl.start))  # the cell of each slot
    mine = np.empty(len(points), np.int64)
    mine[cl.order] = slot_cell
    shape = cl.shape[:dim]
    engine = np.empty(len(points), np.int64)
    cell_indices(np.ascontiguousarray(points.T), shape, shape / space.lengths, engine)
    np.testing.assert_array_equal(mine, engine)
    assert mine.max() > shape[0]  # more than one row of cells: the order of the axes is tested
