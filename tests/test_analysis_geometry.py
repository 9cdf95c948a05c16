"""The analysis honours walls and obstacles: known answers derived from the geometry, and brute force over pairs."""

import math
import warnings

import gsd.hoomd
import numpy as np
import pytest

import flocking
import flocking.analysis as fa
from flocking.space import Space

# --- clusters -------------------------------------------------------------------------------------------------


def facing_rows():
    """Two rows of particles 0.5 apart along x, one at y = 0.2 and one at y = 9.85: 0.35 apart through y = 0."""
    x = np.arange(5.0, 9.0, 0.5)
    return np.r_[np.c_[x, np.full(len(x), 0.2)], np.c_[x, np.full(len(x), 9.85)]]


def test_two_clusters_facing_each_other_across_a_wall_are_two():
    points = facing_rows()
    channel = Space((20.0, 10.0), walls=(False, True))
    cl = fa.Clusters(radius=1.0).compute((channel, points))
    assert cl.num_clusters == 2 and cl.sizes.tolist() == [8, 8]
    assert cl.cluster_idx[:8].tolist() == [0] * 8 and cl.cluster_idx[8:].tolist() == [1] * 8
    assert any("walls on y: no link across them" in note for note in cl.notes)
    # the same rows in a periodic box are one cluster, linked through y = 0
    assert fa.Clusters(radius=1.0).compute((np.array([20.0, 10.0]), points)).num_clusters == 1


def test_a_frame_brings_its_walls():
    # a flocking.Frame (centred coordinates, walls from the file's frame 0): the rows stay two clusters
    points = facing_rows() - [10.0, 5.0]
    velocities = np.tile([0.5, 0.0, 0.0], (len(points), 1))
    frame = flocking.Frame(0, 2, [20.0, 10.0], np.c_[points, np.zeros(len(points))], velocities, walls=[False, True])
    assert fa.Clusters(radius=1.0).compute(frame).num_clusters == 2


def engine_run(tmp_path, **options):
    model = flocking.Model(**{"n": 600, "box": (24.0, 12.0), "noise": 0.8, "seed": 3, **options})
    path = tmp_path / "t.gsd"
    sim = flocking.Simulation(model)
    sim.writers.append(flocking.GSDWriter(path, every=10))
    sim.run(60)
    return model, path


def test_trajectories_and_gsd_files_carry_their_geometry(tmp_path):
    model, path = engine_run(tmp_path, boundary="periodic,wall", obstacles=[{"centre": [6.0, 6.0], "radius": 2.0}])
    with flocking.open(path) as traj:
        last = traj[-1]
        space = Space.of(model, centred=True)
        expected = fa.Clusters(radius=1.0).compute((space, last.positions.astype(float))).sizes
        for system in (traj, path, last):
            assert fa.Clusters(radius=1.0, frames=1).compute(system).sizes.tolist() == expected.tolist()
    with gsd.hoomd.open(path) as raw:  # another reader's trajectory: walls and obstacles from frame 0's log
        cl = fa.Clusters(radius=1.0, frames=1).compute(raw)
    assert cl.sizes.tolist() == expected.tolist()
    assert [note.split(":")[0] for note in cl.notes] == ["walls on y", "1 obstacle"]
    periodic = fa.Clusters(radius=1.0).compute((model.box, last.positions.astype(float)))
    assert periodic.num_clusters < cl.num_clusters  # some clusters touch through the walls


# --- velocity correlation -------------------------------------------------------------------------------------

def brute_correlation(points, du, box, walls, r_max, nbins):
    """Sums of du_i . du_j and ordered pair counts per bin: the nearest image along periodic axes, the plain
    difference between walls."""
    d = points[:, None, :] - points[None, :, :]
    periodic = ~np.asarray(walls)
    d[..., periodic] -= box[periodic] * np.round(d[..., periodic] / box[periodic])
    r = np.sqrt((d**2).sum(axis=2))
    mask = ~np.eye(len(points), dtype=bool) & (r < r_max)
    b = np.minimum((r[mask] / r_max * nbins).astype(int), nbins - 1)
    return np.bincount(b, (du @ du.T)[mask], nbins), np.bincount(b, minlength=nbins)


def sheared(rng, box, n):
    """Points with headings that turn along y: those near y = 0 and y = L_y head opposite ways."""
    points = rng.uniform(0, 1, (n, len(box))) * box
    angle = math.pi * points[:, 1] / box[1]
    u = np.zeros((n, len(box)))
    u[:, 0], u[:, 1] = np.cos(angle), np.sin(angle)
    return points, u


@pytest.mark.parametrize("box, walls", [((20.0, 12.0), (False, True)), ((12.0, 12.0), (True, True)),
                                        ((10.0, 8.0, 6.0), (False, True, False))])
def test_correlation_with_walls_matches_brute_force(box, walls):
    rng = np.random.default_rng(len(box))
    box = np.array(box)
    points, u = sheared(rng, box, 700)
    vc = fa.VelocityCorrelation(r_max=4.0, dr=0.25, method="cells").compute((Space(tuple(box), walls), points, u))
    du = u - u.mean(axis=0)
    sums, counts = brute_correlation(points, du, box, walls, 4.0, 16)
    np.testing.assert_array_equal(vc.pairs, counts)
    np.testing.assert_allclose(vc.correlation * vc.pairs, sums, atol=1e-9)
    # the minimum image through the walls pairs other particles (anti-aligned headings): that fails the comparison
    periodic = fa.VelocityCorrelation(r_max=4.0, dr=0.25, method="cells").compute((box, points, u))
    assert not np.array_equal(periodic.pairs, counts)
    assert np.abs(periodic.correlation * periodic.pairs - sums).max() > 1.0


def brute_grid(points, du, box, walls, dr, r_max):
    """The grid method's own definition: points in cells of side L / round(2 L / dr); a pair at the distance of
    its cells, the cell lags folded along periodic axes only; pairs in one cell at distance 0."""
    shape = np.maximum(np.round(box / (dr / 2)), 1).astype(int)
    h = box / shape
    idx = np.minimum((points / h).astype(int), shape - 1)
    lag = np.abs(idx[:, None, :] - idx[None, :, :])
    periodic = ~np.asarray(walls)
    lag[..., periodic] = np.minimum(lag[..., periodic], shape[periodic] - lag[..., periodic])
    r = np.sqrt(((lag * h) ** 2).sum(axis=2))
    mask = ~np.eye(len(points), dtype=bool) & (r < r_max)
    nbins = int(round(r_max / dr))
    b = np.minimum((r[mask] / dr).astype(int), nbins - 1)
    return np.bincount(b, (du @ du.T)[mask], nbins), np.bincount(b, minlength=nbins)


@pytest.mark.parametrize("walls", [(False, True), (True, True), (False, False)])
def test_correlation_grid_does_not_wrap_across_walls(walls):
    rng = np.random.default_rng(7)
    box = np.array([16.0, 10.0])
    points, u = sheared(rng, box, 500)
    r_max = float(np.linalg.norm(np.where(walls, box, box / 2))) + 0.5  # every pair
    vc = fa.VelocityCorrelation(r_max=r_max, dr=0.5, method="grid").compute((Space(tuple(box), walls), points, u))
    du = u - u.mean(axis=0)
    sums, counts = brute_grid(points, du, box, walls, vc.r[1] - vc.r[0], r_max)
    np.testing.assert_array_equal(vc.pairs, counts)
    np.testing.assert_allclose(vc.correlation[counts > 0] * counts[counts > 0], sums[counts > 0], atol=1e-8)
    assert vc.pairs.sum() == 500 * 499  # the sum rule's pairs: every ordered pair once
    assert (vc.correlation[counts > 0] * counts[counts > 0]).sum() == pytest.approx(-vc.du_squared, abs=1e-8)


def test_correlation_length_beyond_r_max_is_explained():
    # headings u = (cos kx, sin kx): C(r) first vanishes near k r = 2.405 (tests/test_analysis_exact.py), here r = 15.3
    n = 120
    g = (np.arange(n) + 0.5) * (40.0 / n)
    x, y = np.meshgrid(g, g, indexing="ij")
    points = np.c_[x.ravel(), y.ravel()]
    k = 2 * np.pi / 40.0
    u = np.c_[np.cos(k * points[:, 0]), np.sin(k * points[:, 0])]
    vc = fa.VelocityCorrelation(r_max=10.0).compute((40.0, points, u))
    assert math.isnan(vc.correlation_length) and np.all(vc.correlation > 0)
    assert any("correlation length: NaN, C(r) stays positive up to r_max = 10" in note and "larger r_max" in note
               for note in vc.notes)
    assert vc.to_dict()["notes"] == list(vc.notes)
    assert not fa.VelocityCorrelation(r_max=20.0).compute((40.0, points, u)).notes


# --- number fluctuations ------------------------------------------------------------------------------------

def poisson_around(rng, space, n):
    """``n`` points uniform in the free area of ``space`` (rejection)."""
    out = np.empty((0, space.dim))
    while len(out) < n:
        pts = rng.uniform(0, 1, (2 * n, space.dim)) * space.lengths
        out = np.r_[out, pts[~space.in_obstacle(pts)]]
    return out[:n]


def test_poisson_points_around_an_obstacle_give_alpha_one_half():
    rng = np.random.default_rng(21)
    space = Space((60.0, 60.0), obstacles=[(30.0, 30.0, 12.0)])
    frames = [(space, poisson_around(rng, space, 30000)) for _ in range(6)]
    nf = fa.NumberFluctuations().compute(frames)
    assert 0 < nf.alpha_error < 0.03
    assert abs(nf.alpha - 0.5) < 3 * nf.alpha_error
    # the kept sub-boxes hold free area only: binomial counts, dn^2 = <n> (1 - p) with p = <n> / N
    np.testing.assert_allclose(nf.std**2, nf.mean * (1 - nf.mean / 30000), rtol=0.15)
    assert any(note.startswith("sub-boxes that overlap an obstacle are left out") for note in nf.notes)
    # counting the sub-boxes the obstacle covers mixes emptier boxes in: the count varies far more than Poisson
    ignored = fa.NumberFluctuations().compute([(60.0, p) for _, p in frames])
    assert ignored.alpha > nf.alpha + 10 * nf.alpha_error


def test_sub_boxes_touching_an_image_of_an_obstacle_are_left_out():
    # a disc at the left edge: its image reaches into the last column of sub-boxes (periodic x), not with walls
    rng = np.random.default_rng(5)
    points = rng.uniform(0, 40, (4000, 2))
    periodic = fa.NumberFluctuations(sizes=[10.0]).compute((Space((40.0, 40.0), obstacles=[(1.0, 20.0, 3.0)]),
                                                            points))
    walled = fa.NumberFluctuations(sizes=[10.0]).compute((Space((40.0, 40.0), (True, False), obstacles=[
        (1.0, 20.0, 3.0)]), points))
    # 16 sub-boxes of 10: the disc (y 17..23) touches two rows (y 10..20 and 20..30) of the first column, and its
    # image at x = 41 the same rows of the last column
    assert "kept 12 of 16" in periodic.notes[0] and "kept 14 of 16" in walled.notes[0]


# --- bands ---------------------------------------------------------------------------------------------------

def band_points(rng, box, lattice, width, first, gas=2.0, band=4.0):
    """Uniform points at density ``gas`` and, where the phase ``m . x / L`` lies in a stripe of ``width`` along
    the normal starting at phase ``first``, ``band`` more; and the stripe's period along its normal."""
    box = np.asarray(box, float)
    g = np.asarray(lattice) / box
    period = 1 / np.linalg.norm(g)
    volume = np.prod(box)
    pts = rng.uniform(0, 1, (int(gas * volume), len(box))) * box
    extra = rng.uniform(0, 1, (int(3 * band * volume), len(box))) * box  # a share width / period of them kept
    phase = (extra @ g - first) % 1.0
    extra = extra[phase < width / period][: int(band * volume * width / period)]
    return np.r_[pts, extra], period


@pytest.mark.parametrize("box, lattice, angle", [
    ((60.0, 60.0), (1, 0), 0.0), ((60.0, 60.0), (0, 1), 90.0), ((60.0, 60.0), (1, 1), 45.0),
    ((60.0, 60.0), (1, -1), -45.0), ((72.0, 48.0), (1, 1), math.degrees(math.atan(72.0 / 48.0))),
])
def test_bands_along_axes_and_diagonals_are_found_with_their_width(box, lattice, angle):
    # every particle heads along +x: the direction comes from the density, not from the heading
    rng = np.random.default_rng(abs(hash((box, lattice))) % 1000)
    points, period = band_points(rng, box, lattice, width=6.0, first=0.3)
    dp = fa.DensityProfile().compute((np.array(box), points, np.tile([1.0, 0.0], (len(points), 1))))
    assert dp.lattice == lattice and dp.direction_rule == "bands"
    assert dp.angle == pytest.approx(angle, abs=1e-9)
    normal = np.asarray(lattice) / np.asarray(box)
    np.testing.assert_allclose(dp.direction, normal / np.linalg.norm(normal), rtol=1e-12)
    assert dp.period == pytest.approx(period, rel=1e-12)
    assert dp.band_count == 1 and dp.band_width == pytest.approx(6.0, rel=0.1)
    assert dp.band_centres[0] == pytest.approx(0.3 * period + 3.0, abs=0.6)  # from the corner, along the normal
    assert dp.axis_used == (lattice.index(1) if sum(map(abs, lattice)) == 1 else None)


def test_a_band_along_a_body_diagonal_in_3d():
    rng = np.random.default_rng(30)
    points, period = band_points(rng, (20.0, 20.0, 20.0), (1, 1, -1), width=4.0, first=0.5, gas=2.0, band=6.0)
    dp = fa.DensityProfile().compute((20.0, points, np.tile([0.0, 0.0, 1.0], (len(points), 1))))
    assert dp.lattice == (1, 1, -1) and dp.band_count == 1
    assert dp.period == pytest.approx(20.0 / math.sqrt(3)) and dp.band_width == pytest.approx(4.0, rel=0.1)
    assert dp.heading_sign == -1 and math.isnan(dp.angle)
    assert any(note.startswith("angle: NaN in 3D") for note in dp.notes)


def test_a_diagonal_band_moving_at_a_known_speed():
    # a stripe along (1, -1) moving 0.35 per step along its normal (+x-y), frames 10 steps apart
    rng = np.random.default_rng(31)
    box = np.array([50.0, 50.0])
    normal = np.array([1.0, -1.0]) / math.sqrt(2)
    period = 50.0 / math.sqrt(2)
    frames = []
    for t in range(6):
        points, _ = band_points(rng, box, (1, -1), width=5.0, first=(0.1 + 0.35 * 10 * t / period) % 1.0)
        frames.append(fa.snapshots.from_box_points(box, points, np.tile(normal, (len(points), 1)), step=10 * t))
    dp = fa.DensityProfile().compute(frames)
    assert dp.lattice == (1, -1) and dp.heading_sign == 1 and dp.angle == pytest.approx(-45.0)
    assert dp.band_counts.tolist() == [1] * 6
    assert dp.band_speed == pytest.approx(0.35, rel=0.05) and dp.band_width == pytest.approx(5.0, rel=0.1)
    frames = [fa.snapshots.from_box_points(box, f.positions, -f.headings, step=f.step) for f in frames]
    assert fa.DensityProfile().compute(frames).band_speed == pytest.approx(-0.35, rel=0.05)  # against the heading


def test_homogeneous_points_fall_back_to_the_heading():
    rng = np.random.default_rng(32)
    points = rng.uniform(0, 40, (20000, 2))
    u = np.tile([0.6, 0.8], (len(points), 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dp = fa.DensityProfile().compute((40.0, points, u))
    assert dp.frames_with_bands == 0 and dp.direction_rule == "heading"
    assert dp.lattice == (1, 1)  # of the candidates, the nearest to (0.6, 0.8)
    assert any(note.startswith("no significant band along the direction of largest contrast") for note in dp.notes)
    assert any(note.startswith("band_width, band_speed: NaN, no significant band in 1 frame") for note in dp.notes)
    assert max(dp.contrasts) < 0.01


def test_bands_between_walls_run_along_periodic_axes_only():
    rng = np.random.default_rng(33)
    points, _ = band_points(rng, (60.0, 20.0), (1, 0), width=5.0, first=0.5)
    channel = Space((60.0, 20.0), walls=(False, True))
    dp = fa.DensityProfile().compute((channel, points, np.tile([1.0, 0.0], (len(points), 1))))
    assert dp.candidates == [(1, 0)] and dp.lattice == (1, 0) and dp.band_count == 1
    assert any(note.startswith("walls on y: bands are looked for along periodic directions only") for note in dp.notes)
    with pytest.raises(flocking.ParameterError, match="direction: must lie along periodic axes; this box has walls on y"):
        fa.DensityProfile(direction=(1, 1)).compute((channel, points))
    with pytest.raises(flocking.ParameterError, match="system: has walls on x and y, every axis"):
        fa.DensityProfile().compute((Space((60.0, 20.0), walls=(True, True)), points))


def test_an_obstacle_takes_volume_from_its_slabs():
    # Poisson points around a disc: per free volume the profile is flat (within its shot noise), and no band
    rng = np.random.default_rng(34)
    space = Space((60.0, 60.0), obstacles=[(30.0, 30.0, 14.0)])
    points = poisson_around(rng, space, 40000)
    u = np.tile([1.0, 0.0], (len(points), 1))
    dp = fa.DensityProfile(direction=0, bin_width=2.0).compute((space, points, u))
    free = 3600 - math.pi * 14.0**2
    expected = 40000 / free
    slab_free = 2.0 * 60.0 - 2.0 * 2.0 * np.sqrt(np.clip(14.0**2 - (dp.x - 30.0) ** 2, 0, None))  # chord x width
    error = np.sqrt(expected * slab_free) / slab_free  # shot noise of a slab's density
    assert np.all(np.abs(dp.density - expected) < 5 * error)
    assert dp.frames_with_bands == 0 and dp.direction_rule == "given"
    # counting the obstacle's slabs as whole volume, their density would read up to 47 % low
    assert (dp.profiles[-1] * slab_free / 120.0).min() < 0.6 * expected


# --- MSD and box counting ---------------------------------------------------------------------------------

def test_msd_unwraps_along_periodic_axes_only():
    # one particle moving 14 along y (walls) and 3 along x (periodic, box 20) per frame: no wrap along y
    box = Space((20.0, 20.0), walls=(False, True))
    frames = [(box, np.array([[(3.0 * t) % 20, 1.0 + 14.0 * (t % 2)]]), np.array([[1.0, 0.0]])) for t in range(4)]
    msd = fa.MeanSquareDisplacement().compute(frames, steps=[0, 1, 2, 3])
    # displacements: lag 1: (3, +-14); lag 2: (6, 0); lag 3: (9, +-14)
    np.testing.assert_allclose(msd.msd, [9 + 196, 36, 81 + 196])


def test_box_counting_says_what_obstacles_do():
    rng = np.random.default_rng(35)
    space = Space((32.0, 32.0), obstacles=[(16.0, 16.0, 8.0)])
    frame = fa.snapshots.from_box_points(space, poisson_around(rng, space, 50000))
    bc = fa.BoxCounting().compute(frame)
    share = math.pi * 8.0**2 / 32.0**2
    assert f"obstacles cover {share:.1%} of the box" in bc.notes[0]
    assert abs(bc.dimension - 2) < 0.1
