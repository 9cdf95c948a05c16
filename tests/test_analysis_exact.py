"""Validation of flocking.analysis against exact cases."""

import json
import math
import warnings

import numpy as np
import pytest

import flocking.analysis as fa


# --- number fluctuations -------------------------------------------------------------

@pytest.mark.parametrize("dim", [2, 3])
def test_uniform_points_give_alpha_one_half(dim):
    rng = np.random.default_rng(10 + dim)
    box = 60.0 if dim == 2 else 24.0
    frames = [(box, rng.uniform(0, box, (30000, dim))) for _ in range(6)]
    nf = fa.NumberFluctuations().compute(frames)
    assert 0 < nf.alpha_error < 0.03
    assert abs(nf.alpha - 0.5) < 3 * nf.alpha_error
    # Poisson: dn^2 = <n> (1 - p) at every size
    p = nf.mean / 30000
    np.testing.assert_allclose(nf.std**2, nf.mean * (1 - p), rtol=0.15)


def test_clumped_points_give_alpha_one_half_and_twenty_times_the_poisson_variance():
    # whole clumps of 20 particles at uniform positions: dn ~ <n>^(1/2) at large scales but the
    # count is 20 x a Poisson count, so dn^2 = 20 <n> exactly in expectation
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 50, (2000, 2))
    pts = np.repeat(centres, 20, axis=0)
    nf = fa.NumberFluctuations(fit_range=(20, 1e9)).compute((50.0, pts))
    assert abs(nf.alpha - 0.5) < 4 * nf.alpha_error + 0.02
    np.testing.assert_allclose(nf.std[nf.mean > 20] ** 2 / nf.mean[nf.mean > 20], 20, rtol=0.25)


# --- box counting ------------------------------------------------------------------

def sierpinski_points(level):
    i, j = np.indices((2**level, 2**level))
    i, j = i[(i & j) == 0], j[(i & j) == 0]
    return np.c_[i + 0.5, j + 0.5]


def test_sierpinski_points_give_log3_over_log2():
    pts = sierpinski_points(9)
    bc = fa.BoxCounting().compute(pts, box=2.0**9)
    assert bc.dimension == pytest.approx(math.log(3) / math.log(2), abs=1e-9)
    assert bc.dimension_error < 1e-9
    eps = bc.scales[bc.fitted]
    np.testing.assert_array_equal(bc.counts[bc.fitted], 3 ** np.round(np.log2(2.0**9 / eps)))


def test_sierpinski_chaos_game_points():
    rng = np.random.default_rng(0)
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    p = np.zeros((200000, 2))
    x = np.array([0.3, 0.3])
    choice = rng.integers(0, 3, len(p))
    for t in range(len(p)):
        x = 0.5 * (x + corners[choice[t]])
        p[t] = x
    bc = fa.BoxCounting().compute(p[100:], box=1.0)
    assert bc.dimension == pytest.approx(math.log(3) / math.log(2), abs=max(3 * bc.dimension_error, 0.02))


def test_square_and_line_images():
    full = np.ones((128, 128), bool)
    assert fa.BoxCounting().compute(full).dimension == pytest.approx(2.0, abs=1e-12)
    line = np.zeros((128, 128), bool)
    line[37, :] = True
    assert fa.BoxCounting().compute(line).dimension == pytest.approx(1.0, abs=1e-12)
    i, j = np.indices((256, 256))
    assert fa.BoxCounting().compute((i & j) == 0).dimension == pytest.approx(math.log(3) / math.log(2))


def test_square_and_line_points():
    rng = np.random.default_rng(1)
    square = rng.uniform(0, 10, (200000, 2))
    bc = fa.BoxCounting().compute(square, box=10.0)
    assert abs(bc.dimension - 2) < max(3 * bc.dimension_error, 0.01)
    line = np.c_[rng.uniform(0, 10, 50000), np.full(50000, 3.3)]
    bc = fa.BoxCounting().compute(line, box=10.0)
    assert abs(bc.dimension - 1) < max(3 * bc.dimension_error, 0.01)


def test_fit_through_two_points_has_no_error():
    from flocking.analysis.base import fit_line

    assert math.isnan(fit_line([0.0, 1.0], [1.0, 3.0])[2])
    assert fit_line([0.0, 1.0, 2.0], [1.0, 3.0, 5.0])[2] == 0.0
    # with known errors, the formal error needs no degree of freedom: sigma sqrt(2) / (x1 - x0)
    assert fit_line([0.0, 2.0], [1.0, 3.0], [0.1, 0.1])[2] == pytest.approx(0.1 * math.sqrt(2) / 2)


def test_boxcount_of_few_points_in_3d_is_flagged():
    # the tester's case: 1000 points in 3D leave two sizes (L/2: 8 boxes, L/4: 64) before the count
    # passes N/10 = 100; a line through two points has no error (it read "D 2.644 +- 0.000")
    rng = np.random.default_rng(9)
    with pytest.warns(RuntimeWarning, match="only two box sizes"):
        bc = fa.BoxCounting().compute(rng.uniform(0, 10, (1000, 3)), box=10.0)
    assert bc.fitted.sum() == 2 and math.isnan(bc.dimension_error)
    assert bc.dimension == pytest.approx(3.0, abs=0.05)  # 8 and 64 boxes all occupied
    assert json.loads(json.dumps(bc.to_dict()))["dimension_error"] is None
    with warnings.catch_warnings():  # three sizes or more, or a range asked for: nothing to flag
        warnings.simplefilter("error")
        assert fa.BoxCounting().compute(rng.uniform(0, 10, (10000, 3)), box=10.0).fitted.sum() == 3
        fa.BoxCounting(fit_range=(2.5, 5.0)).compute(rng.uniform(0, 10, (1000, 3)), box=10.0)


def test_boxcount_fit_range():
    i, j = np.indices((64, 64))
    bc = fa.BoxCounting(fit_range=(2, 16)).compute((i & j) == 0)
    assert bc.fit_range_used == (2.0, 16.0)
    assert bc.fitted.sum() == 4


# --- velocity correlation ----------------------------------------------------------

@pytest.mark.parametrize("method", ["cells", "grid"])
@pytest.mark.parametrize("dim", [2, 3])
def test_correlation_sum_rule(method, dim):
    rng = np.random.default_rng(dim)
    box = np.array([9.0, 7.0, 6.0][:dim])
    pts = rng.uniform(0, 1, (400, dim)) * box
    u = rng.normal(size=(400, dim)) + 0.5
    r_max = 0.5 * np.linalg.norm(box) + 0.1
    vc = fa.VelocityCorrelation(r_max=r_max, dr=0.3, method=method).compute((box, pts, u))
    ok = vc.pairs > 0
    total = (vc.correlation[ok] * vc.pairs[ok]).sum()
    assert total == pytest.approx(-vc.du_squared, rel=1e-9, abs=1e-9)
    assert vc.pairs.sum() == 400 * 399


def brute_force_correlation(pts, u, box, r_max, nbins):
    du = u / np.linalg.norm(u, axis=1, keepdims=True)
    du = du - du.mean(axis=0)
    d = pts[:, None, :] - pts[None, :, :]
    d -= box * np.round(d / box)
    r = np.linalg.norm(d, axis=2)
    dot = du @ du.T
    mask = ~np.eye(len(pts), dtype=bool) & (r < r_max)
    b = np.minimum((r[mask] / r_max * nbins).astype(int), nbins - 1)
    return np.bincount(b, dot[mask], nbins), np.bincount(b, minlength=nbins)


def test_correlation_cells_match_brute_force():
    rng = np.random.default_rng(5)
    box = np.array([20.0, 15.0])
    pts = rng.uniform(0, 1, (600, 2)) * box
    u = np.c_[np.cos(pts[:, 0] / 3), np.sin(pts[:, 0] / 3)]  # correlated headings
    vc = fa.VelocityCorrelation(r_max=4.0, dr=0.25, method="cells").compute((box, pts, u))
    sums, counts = brute_force_correlation(pts, u, box, 4.0, 16)
    np.testing.assert_array_equal(vc.pairs, counts)
    np.testing.assert_allclose(vc.correlation * vc.pairs, sums, atol=1e-9)
    assert vc.correlation[0] > 0


def test_correlation_length_of_a_known_profile():
    # headings u = (cos(kx), sin(kx)) on a dense lattice: C(r) ~ <cos(k dx)> vanishes first
    # where the angular average of cos(k r cos(phi)) = J0(k r) does, k r = 2.405
    n = 160
    g = (np.arange(n) + 0.5) * (40.0 / n)
    x, y = np.meshgrid(g, g, indexing="ij")
    pts = np.c_[x.ravel(), y.ravel()]
    k = 2 * np.pi / 40.0
    u = np.c_[np.cos(k * pts[:, 0]), np.sin(k * pts[:, 0])]
    vc = fa.VelocityCorrelation(r_max=20.0, dr=0.25).compute((40.0, pts, u))
    assert vc.correlation_length == pytest.approx(2.405 / k, rel=0.02)


# --- clusters ----------------------------------------------------------------------

def test_clusters_hand_built_and_periodic():
    box = np.array([10.0, 8.0])
    pts = np.array([
        [0.1, 4.0], [9.6, 4.0], [9.2, 4.2],   # a chain across x = 0
        [5.0, 0.2], [5.0, 7.7],                # a pair across y = 0
        [5.0, 4.0], [5.99, 4.0],               # strictly closer than 1
        [2.0, 2.0], [3.0, 2.0],                # exactly 1 apart: not linked
    ])
    cl = fa.Clusters(radius=1.0).compute((box, pts))
    lab = cl.cluster_idx
    assert lab[0] == lab[1] == lab[2] == 0
    assert lab[3] == lab[4] and lab[5] == lab[6] and lab[3] != lab[5]
    assert lab[7] != lab[8]
    assert cl.sizes.tolist() == [3, 2, 2, 1, 1]
    assert cl.num_clusters == 5 and cl.largest_fraction == pytest.approx(3 / 9)


def test_cluster_averages_over_frames():
    # frame 1: sizes 3, 2, 1; frame 2: sizes 4, 1, 1 -> n_s summed: {1: 3, 2: 1, 3: 1, 4: 1}
    one = np.array([[1.0, 1.0], [1.5, 1.0], [2.0, 1.0], [5.0, 5.0], [5.5, 5.0], [8.0, 2.0]])
    two = np.array([[1.0, 1.0], [1.5, 1.0], [2.0, 1.0], [2.5, 1.0], [5.0, 5.0], [8.0, 2.0]])
    cl = fa.Clusters(radius=0.6).compute([(10.0, one), (10.0, two)])
    assert cl.size_values.tolist() == [1, 2, 3, 4]
    assert cl.size_counts_total.tolist() == [3, 1, 1, 1]
    assert cl.size_counts_per_frame.tolist() == [1.5, 0.5, 0.5, 0.5]
    assert cl.number_average_size == pytest.approx(12 / 6)           # sum s n_s / sum n_s
    assert cl.weight_average_size == pytest.approx((3 + 4 + 9 + 16) / 12)  # sum s^2 n_s / sum s n_s
    assert cl.largest_fraction == pytest.approx(4 / 6)               # the last frame
    assert cl.largest_fraction_mean == pytest.approx((3 / 6 + 4 / 6) / 2)
    assert cl.num_frames == 2


def test_clusters_3d_and_brute_force():
    rng = np.random.default_rng(8)
    pts = rng.uniform(0, 6, (500, 3))
    cl = fa.Clusters(radius=0.7).compute((6.0, pts))
    d = pts[:, None] - pts[None]
    d -= 6.0 * np.round(d / 6.0)
    adj = np.linalg.norm(d, axis=2) < 0.7
    from scipy.sparse.csgraph import connected_components
    ncomp, lab = connected_components(adj)
    assert cl.num_clusters == ncomp
    # same partition
    pairs = lab[:, None] == lab[None]
    np.testing.assert_array_equal(pairs, cl.cluster_idx[:, None] == cl.cluster_idx[None])


@pytest.mark.parametrize("walls", [(False, False), (True, False)])
def test_clusters_by_the_k_nearest_are_the_components_of_the_knn_graph(walls):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from flocking.space import Space

    rng = np.random.default_rng(9)
    box = np.array([12.0, 9.0])
    pts = np.concatenate([rng.normal(3.0, 0.6, (80, 2)), rng.normal(8.5, 0.6, (80, 2)), rng.uniform(0, 9, (40, 2))])
    pts = np.mod(pts, box)
    space = Space(tuple(box), walls)
    d = pts[None] - pts[:, None]
    if not walls[0]:
        d[..., 0] -= box[0] * np.round(d[..., 0] / box[0])
    d[..., 1] -= box[1] * np.round(d[..., 1] / box[1])
    r = np.linalg.norm(d, axis=2)
    np.fill_diagonal(r, np.inf)
    for k in (1, 3):
        near = np.argsort(r, axis=1, kind="stable")[:, :k]  # no exact ties among random points
        graph = coo_matrix((np.ones(near.size), (np.repeat(np.arange(len(pts)), k), near.ravel())), (200, 200))
        ncomp, lab = connected_components(graph, directed=True, connection="weak")
        cl = fa.Clusters(k=k).compute((space, pts))
        assert cl.num_clusters == ncomp and cl.k_used == k and math.isnan(cl.radius_used)
        np.testing.assert_array_equal(lab[:, None] == lab[None], cl.cluster_idx[:, None] == cl.cluster_idx[None])


def test_clusters_take_radius_or_k_not_both_nor_too_many():
    with pytest.raises(ValueError, match="k: links by distance or by the k nearest, not both"):
        fa.Clusters(radius=1.0, k=3)
    with pytest.raises(ValueError, match=r"k: must be a whole number >= 1 \(got 0\)"):
        fa.Clusters(k=0)
    with pytest.raises(ValueError, match="k: must be at most the number of other particles, 2 "):
        fa.Clusters(k=3).compute((5.0, np.zeros((3, 2))))


def test_clusters_radius_larger_than_half_box():
    pts = np.array([[0.0, 0.0], [1.5, 0.0], [0.0, 1.5]])
    cl = fa.Clusters(radius=1.6).compute((3.0, pts))
    assert cl.num_clusters == 1
