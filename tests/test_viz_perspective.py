"""3D pictures: cones ray-cast exactly, nearest in front, lit from the upper left, in the box's frame."""

from __future__ import annotations

import numpy as np
import pytest

from flocking.viz.colors import THEMES
from flocking.viz.perspective import ASPECT, LENGTH, Camera, glyph_length, perspective_image

BOX = (10.0, 10.0, 10.0)
SIZE = 201


def silhouette(img, theme):
    """Pixels that differ from the picture of the empty box (its background and wire frame)."""
    empty = perspective_image(np.zeros((0, 3)), np.zeros((0, 3)), BOX, SIZE, THEMES[theme])
    return np.abs(img - empty).max(axis=2) > 0.05


def one_cone(direction, theme="dark", length=4.0, colors=None):
    cam = Camera(BOX, SIZE)
    heading = np.asarray(direction, float) @ cam.rotation  # camera coordinates -> world
    img = perspective_image(np.zeros((1, 3)), heading[None, :], BOX, SIZE, THEMES[theme], length=length,
                            colors=colors)
    return img, cam


def test_a_cone_across_the_view_points_its_tip_along_the_heading():
    img, cam = one_cone([1.0, 0.0, 0.0])                               # along the picture's +x
    mask = silhouette(img, "dark")
    cols = np.flatnonzero(mask.any(axis=0))
    heights = mask.sum(axis=0)[cols]
    # its projected length is the cone's, seen from the camera's distance (a pixel of rim each end)
    expected = cam.focal * 4.0 / cam.distance
    assert abs(len(cols) - expected) <= 2.5
    # wide at the base (left), pointed at the tip (right)
    third = len(cols) // 3
    assert heights[:third].mean() > 2.5 * heights[-third:].mean()
    assert heights[:third].max() == pytest.approx(2 * ASPECT * expected, abs=2.5)


def test_a_cone_seen_from_its_tip_is_a_round_disc():
    img, cam = one_cone([0.0, 0.0, -1.0])                              # toward the camera
    mask = silhouette(img, "dark")
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    assert abs(len(rows) - len(cols)) <= 1
    radius_px = cam.focal * ASPECT * 4.0 / (cam.distance + 2.0)       # the base, 2 behind the centre
    assert len(cols) == pytest.approx(2 * radius_px, abs=2.5)


def test_the_lit_side_is_brighter_than_the_side_away_from_the_light():
    img, _ = one_cone([1.0, 0.0, 0.0], colors=np.array([[0.7, 0.7, 0.7]]))
    mask = silhouette(img, "dark")
    rows = np.flatnonzero(mask.any(axis=1))
    middle = (rows[0] + rows[-1]) / 2
    brightness = img.mean(axis=2)
    upper = brightness[:int(middle)][mask[:int(middle)]]
    lower = brightness[int(middle) + 1:][mask[int(middle) + 1:]]
    assert upper.mean() > 1.3 * lower.mean()                          # the key light is above


def test_the_nearest_particle_hides_the_ones_behind_it_in_any_input_order():
    cam = Camera(BOX, SIZE)
    near, far = -2.0 * cam.forward, 2.0 * cam.forward                 # on the line of sight through the centre
    heads = np.array([cam.right, cam.right])
    colours = np.array([[0.9, 0.1, 0.1], [0.1, 0.1, 0.9]])
    a = perspective_image(np.array([near, far]), heads, BOX, SIZE, THEMES["dark"], length=2.0, colors=colours)
    b = perspective_image(np.array([far, near]), heads[::-1], BOX, SIZE, THEMES["dark"], length=2.0,
                          colors=colours[::-1])
    assert np.array_equal(a, b)
    seen = a[silhouette(a, "dark")]
    assert len(seen) > 100 and (seen[:, 0] > seen[:, 2]).all()        # red, the near one, hides blue


def test_the_box_frame_is_in_view_and_hidden_behind_particles():
    theme = THEMES["light"]
    empty = perspective_image(np.zeros((0, 3)), np.zeros((0, 3)), BOX, SIZE, theme)
    edges = np.abs(empty - np.asarray(theme.background)).max(axis=2) > 0.02
    assert edges.sum() > 600 and not edges[:3].any() and not edges[-3:].any()
    cam = Camera(BOX, SIZE)
    u, v, _ = cam.project(np.array([[5.0, 5.0, 5.0], [-5.0, -5.0, -5.0]]))
    for x, y in zip(u, v):                                             # corners lie on drawn edges
        assert edges[int(y) - 2:int(y) + 3, int(x) - 2:int(x) + 3].any()
    # a wall of particles in front of the far corner hides it
    far_corner = 5.0 * np.sign(cam.forward)                           # the corner farthest from the eye
    fu, fv, _ = cam.project(far_corner[None, :])
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9), [0.0]), -1).reshape(-1, 3)
    wall = grid @ np.stack([cam.right, cam.up, cam.forward]) + 0.6 * far_corner
    covered = perspective_image(wall, np.tile(cam.right, (len(wall), 1)), BOX, SIZE, theme, length=1.0,
                                colors=np.tile([0.2, 0.8, 0.2], (len(wall), 1)))
    patch = covered[int(fv[0]) - 1:int(fv[0]) + 2, int(fu[0]) - 1:int(fu[0]) + 2].reshape(-1, 3)
    assert (patch[:, 1] > patch[:, 0] + 0.1).all()                    # green particles, no grey edge


def test_default_cones_are_a_fixed_fraction_of_the_spacing():
    assert glyph_length(65536, (32.0, 32.0, 32.0)) == pytest.approx(LENGTH * 0.5 ** (1 / 3) * 1.0)
    assert glyph_length(8, (10.0, 10.0, 10.0)) == pytest.approx(1.0)    # at most a tenth of the box
    assert glyph_length(65536, (32.0, 32.0, 32.0), scale=2.0) == pytest.approx(2 * LENGTH * 0.5 ** (1 / 3))
