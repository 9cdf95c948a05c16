"""Density maps: mass, periodicity, the order estimator's statistics, and the colour bar's honesty."""

from __future__ import annotations

import numpy as np
import pytest

from flocking.viz.colors import THEMES, angle_colors
from flocking.viz.density import (GAMMA, SIGNIFICANT, DensityField, density_colormap, density_image,
                                  density_scale, grid_shape, nice_ceiling)

BOX = (40.0, 40.0)


def random_headings(rng, n):
    a = rng.uniform(0, 2 * np.pi, n)
    return np.stack([np.cos(a), np.sin(a)], axis=1)


def test_smoothing_keeps_every_particle_and_wraps_around_the_box():
    rng = np.random.default_rng(1)
    pos = rng.uniform(-20, 20, (3000, 2))
    field = DensityField(pos, random_headings(rng, 3000), BOX, (80, 80))
    # the kernel sums to one, so the mean density is N / area to rounding
    assert field.density.mean() == pytest.approx(3000 / 1600, rel=1e-12)
    one = DensityField(np.array([[19.9, 0.0]]), np.array([[1.0, 0.0]]), BOX, (80, 80))
    row = one.density[40]
    assert row[0] > 0.2 * row[-1] and row[0] > 100 * row[40]        # spreads across the +x edge to -x


def test_aligned_particles_are_fully_ordered_and_point_their_way():
    rng = np.random.default_rng(2)
    pos = rng.uniform(-20, 20, (6000, 2))
    heads = np.tile([np.cos(2.0), np.sin(2.0)], (6000, 1))
    field = DensityField(pos, heads, BOX, (64, 64))
    # |S| = W1 exactly for aligned headings, and every pixel is far above the significance bar
    assert field.significance.min() > SIGNIFICANT
    assert np.allclose(field.order, 1.0, atol=1e-9) and np.allclose(field.angle, 2.0, atol=1e-9)


def test_random_headings_are_grey_except_by_the_chance_the_threshold_allows():
    # for random headings S is nearly Gaussian with E|S|^2 = W2, so |S|^2 / W2 is
    # exponential with mean 1: colour starts above SIGNIFICANT / 2, on a fraction
    # exp(-SIGNIFICANT / 2) of the pixels on average (0.0067)
    rng = np.random.default_rng(3)
    n = 20000
    field = DensityField(rng.uniform(-20, 20, (n, 2)), random_headings(rng, n), BOX, (128, 128))
    assert abs(field.significance.mean() - 1.0) < 0.2                 # |S|^2 / W2 averages 1
    expected = np.exp(-SIGNIFICANT / 2)
    # pixels come in correlated patches, one per kernel area (4 pi sigma^2 bins)
    patches = 128 * 128 / (4 * np.pi * field.sigma_order**2)
    bound = expected + 5 * np.sqrt(expected / patches)
    assert (field.order > 0).mean() < bound
    assert field.order.mean() < 0.01
    # the naive estimate |S| / W1 shows strong colour everywhere: what the old maps did
    naive = np.sqrt(field.significance / field.count)
    assert naive.mean() > 0.1


def test_few_particles_never_show_an_order():
    # 2 particles alone in the box, aligned: too few to mean anything
    pos = np.array([[0.0, 0.0], [0.3, 0.2]])
    field = DensityField(pos, np.array([[1.0, 0.0], [1.0, 0.0]]), BOX, (64, 64))
    assert field.order.max() == 0.0


def test_image_brightness_follows_the_colour_bar():
    rng = np.random.default_rng(4)
    pos = np.vstack([rng.uniform([-20, -20], [-10, 20], (4000, 2)), rng.uniform([0, -20], [20, 20], (1000, 2))])
    heads = np.vstack([np.tile([0.0, 1.0], (4000, 1)), random_headings(rng, 1000)])
    field = DensityField(pos, heads, BOX, (80, 80))
    for name in ("dark", "light"):
        t = THEMES[name]
        vmax = density_scale([field])
        img = density_image(field, t, vmax)
        cmap = density_colormap(t)
        # a disordered pixel has exactly the colour bar's colour at its density
        gas = field.order == 0
        level = np.clip(field.density[gas] / vmax, 0, 1) ** GAMMA
        assert np.abs(img[gas] - cmap(level)[:, :3]).max() < 1.5 / 255 + 1 / 256
        # the band (heading +y) shows the +y colour, at the band's brightness
        band = (field.order > 0.95) & (field.density > 0.8 * np.percentile(field.density, 99))
        assert band.sum() > 50
        alpha = (field.density[band] / vmax) ** GAMMA
        expected = np.asarray(t.background) + alpha[:, None] * (angle_colors(np.pi / 2, t, 1.0, ink=True)
                                                                - np.asarray(t.background))
        assert np.abs(img[band] - expected).max() < 0.02


def test_scale_tops_the_densest_regions_with_a_round_number():
    rng = np.random.default_rng(5)
    uniform = DensityField(rng.uniform(-20, 20, (3200, 2)), random_headings(rng, 3200), BOX, (64, 64))
    assert density_scale([uniform]) == nice_ceiling(max(np.percentile(uniform.density, 99.5), 4.0)) == 4.0
    clustered = DensityField(rng.normal(0, 2, (3200, 2)), random_headings(rng, 3200), BOX, (64, 64))
    top = density_scale([uniform, clustered])
    assert top >= np.percentile(clustered.density, 99.5) and top == nice_ceiling(top)


def test_grid_has_square_bins_and_the_pixels_of_the_longer_side():
    assert grid_shape((40.0, 40.0), 300) == (300, 300)
    assert grid_shape((80.0, 20.0), 400) == (100, 400)
    assert grid_shape((10.0, 30.0), 300) == (300, 100)
