"""flocking.space: pairs, cells and obstacle overlaps against brute force written from the definitions."""

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import flocking
from flocking.neighbour_query import cell_shape
from flocking.space import Space


def brute_pairs(points, box, walls, cutoff):
    """Every pair i < j closer than ``cutoff``: the nearest image along periodic axes
    (``d - L round(d / L)``), the plain difference along axes with walls."""
    points = np.asarray(points, float)
    box = np.asarray(box, float)
    d = points[None, :, :] - points[:, None, :]
    periodic = ~np.asarray(walls)
    d[..., periodic] -= box[periodic] * np.round(d[..., periodic] / box[periodic])
    r = np.sqrt((d**2).sum(axis=2))
    i, j = np.nonzero(np.triu(r < cutoff, k=1))
    return {(int(a), int(b)): r[a, b] for a, b in zip(i, j)}


def found(pairs):
    assert np.all(pairs.i < pairs.j)
    out = {(int(a), int(b)): r for a, b, r in zip(pairs.i, pairs.j, pairs.distance)}
    assert len(out) == len(pairs.i), "a pair was listed twice"
    return out


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("walls", ["none", "first", "last", "all"])
@pytest.mark.parametrize("box_side, cutoff", [(10.0, 1.3), (3.0, 1.1), (2.5, 2.0), (4.0, 3.5)])
def test_pairs_match_brute_force(dim, walls, box_side, cutoff):
    # boxes of 1, 2 and many cells per axis, cutoffs beyond half the box included
    rng = np.random.default_rng(dim * 100 + int(box_side * 10))
    box = box_side * np.array([1.0, 0.8, 1.2][:dim])
    wall = {"none": [False] * dim, "first": [True] + [False] * (dim - 1), "last": [False] * (dim - 1) + [True],
            "all": [True] * dim}[walls]
    points = rng.uniform(0, 1, (300 if dim == 2 else 400, dim)) * box
    points[:4] = 0.0  # on the lower sides ...
    points[4:8] = box * np.where(wall, 1.0, 0.999999)  # ... and on the upper ones (a wall is a closed side)
    expected = brute_pairs(points, box, wall, cutoff)
    got = found(Space(tuple(box), tuple(wall)).pairs(points, cutoff))
    assert got.keys() == expected.keys()
    np.testing.assert_allclose([got[k] for k in expected], [expected[k] for k in expected], rtol=1e-12)


def test_no_pair_across_a_wall_but_across_a_periodic_side():
    # the same two points 0.4 apart through y = 0: linked when y is periodic, not with a wall there
    points = [[5.0, 0.1], [5.0, 9.7]]
    assert len(Space((10.0, 10.0)).pairs(points, 1.0).i) == 1
    assert len(Space((10.0, 10.0), walls=(False, True)).pairs(points, 1.0).i) == 0
    assert len(Space((10.0, 10.0), walls=(True, False)).pairs(points, 1.0).i) == 1


def test_pairs_are_strictly_closer_than_the_cutoff():
    pairs = Space((10.0, 10.0)).pairs([[1.0, 1.0], [2.0, 1.0], [1.0, 1.999]], 1.0)
    assert list(zip(pairs.i.tolist(), pairs.j.tolist())) == [(0, 2)]


def test_blocks_split_the_pairs_without_loss():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 20, (3000, 2))
    space = Space((20.0, 20.0), walls=(True, False))
    whole = found(space.pairs(points, 1.0))
    blocks = list(space.pair_blocks(points, 1.0, block=500))
    # 400 cells of about 90 pairs each: a block holds whole cells, 500 pairs at most unless one cell has more
    assert len(blocks) > 50 and all(len(b.i) <= 500 for b in blocks)
    parts = {}
    for b in blocks:
        parts.update(found(b))
    assert parts == whole and sum(len(b.i) for b in blocks) == len(whole)


def test_points_in_the_frame_coordinates():
    # centred points (a GSD frame) give the same pairs as the same points at the corner
    rng = np.random.default_rng(4)
    points = rng.uniform(0, 8, (200, 2))
    corner = Space((8.0, 8.0), walls=(False, True))
    centred = corner.with_origin(-4.0)
    assert found(centred.pairs(points - 4.0, 1.0)).keys() == found(corner.pairs(points, 1.0)).keys()


@given(st.lists(st.tuples(st.floats(0, 6), st.floats(0, 6)), min_size=2, max_size=40),
       st.booleans(), st.booleans(), st.floats(0.1, 7.0))
@settings(max_examples=60, deadline=None)
def test_pairs_hypothesis(points, wall_x, wall_y, cutoff):
    box, walls = (6.0, 5.0), (wall_x, wall_y)
    points = np.minimum(np.array(points), [6.0, 5.0])
    space = Space(box, walls)
    points = space.inside(points)
    assert found(space.pairs(points, cutoff)).keys() == brute_pairs(points, box, walls, cutoff).keys()


def test_cell_shape_is_at_least_the_cutoff_wide():
    for lengths, cutoff, n in [((10.0, 3.0), 1.0, 100), ((100.0, 100.0), 1.0, 10), ((7.0, 7.0, 7.0), 2.5, 1000)]:
        shape = cell_shape(np.array(lengths), cutoff, n)
        assert np.all(np.array(lengths) / shape[: len(lengths)] >= cutoff)
        assert np.prod(shape) <= max(4 * n, 64)


def test_space_of_a_model_and_of_its_frames(tmp_path):
    model = flocking.Model(n=50, box=(12.0, 8.0), boundary="periodic,wall",
                           obstacles=[{"centre": [3, 4], "radius": 1.5}])
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(tmp_path / "t.gsd", every=5))
    sim.run(10)
    with flocking.open(tmp_path / "t.gsd") as traj:
        frame = traj[-1]
        space = Space.of_frame(frame)
        assert space == Space.of(model, centred=True)
        assert space.with_origin(0.0) == Space.of(model)
        assert not space.in_obstacle(frame.positions.astype(float)).any()  # the engine keeps them out
        assert space.in_obstacle([[3.0 - 6.0, 4.0 - 4.0]]).tolist() == [True]


def test_inside_wraps_periodic_axes_and_clips_walls():
    space = Space((4.0, 4.0), walls=(False, True), origin=(-2.0, -2.0))
    assert space.inside([[2.0, 2.00001], [-2.5, -3.0]]).tolist() == [[-2.0, 2.0], [1.5, -2.0]]


def brute_touch(space, lower, side, samples=60):
    """Whether any of a fine grid of points of the cube lies inside an obstacle (an image
    included), and how far the nearest sample is from the surface."""
    g = (np.arange(samples + 1) / samples) * side
    cube = np.stack([a.ravel() for a in np.meshgrid(*[g] * space.dim, indexing="ij")], axis=1)
    out, margin = [], []
    for corner in lower:
        pts = corner + cube
        best = np.inf
        for row in space.obstacles:
            c, radius = np.array(row[:-1]), row[-1]
            for image in itertools.product(*[(-1, 0, 1) if p else (0,) for p in space.periodic]):
                d = np.sqrt(((pts - c - np.array(image) * space.lengths) ** 2).sum(axis=1)).min() - radius
                best = min(best, d)
        out.append(best < 0)
        margin.append(abs(best))
    return np.array(out), np.array(margin)


@pytest.mark.parametrize("walls", [(False, False), (True, False), (True, True)])
def test_boxes_touching_obstacles_match_sampling(walls):
    space = Space((10.0, 8.0), walls, obstacles=((0.8, 4.0, 1.5), (6.0, 7.5, 1.0)))
    side = 1.25
    lower = np.stack([a.ravel() for a in np.meshgrid(np.arange(8) * side, np.arange(6) * side, indexing="ij")], 1)
    expected, margin = brute_touch(space, lower, side)
    got = space.boxes_touch_obstacle(lower, side)
    sure = margin > side / 60 * 1.5  # the sampling can miss a cube that only grazes a disc
    assert sure.sum() > 40
    np.testing.assert_array_equal(got[sure], expected[sure])
    if walls[0]:  # no image of the first disc across x = 0: the cubes at x = 8.75 stay clear of it
        assert not got[(lower[:, 0] == 8.75) & (lower[:, 1] == 3.75)].any()
    else:
        assert got[(lower[:, 0] == 8.75) & (lower[:, 1] == 3.75)].all()


@pytest.mark.parametrize("dim, walls", [(2, (False, True)), (3, (True, False, True)), (2, (False, False))])
def test_pair_histogram_matches_the_pairs(dim, walls):
    rng = np.random.default_rng(dim)
    box = np.array([7.0, 5.0, 6.0][:dim])
    points = rng.uniform(0, 1, (500, dim)) * box
    vectors = rng.normal(size=(500, dim))
    expected = brute_pairs(points, box, walls, 2.5)
    keys = np.array(list(expected.keys()))
    r = np.array(list(expected.values()))
    b = np.minimum((r / 2.5 * 10).astype(int), 9)
    counts, sums = Space(tuple(box), walls).pair_histogram(points, 2.5, 10, vectors)
    np.testing.assert_array_equal(counts, np.bincount(b, minlength=10))
    dots = (vectors[keys[:, 0]] * vectors[keys[:, 1]]).sum(axis=1)
    np.testing.assert_allclose(sums, np.bincount(b, weights=dots, minlength=10), rtol=1e-12, atol=1e-12)
