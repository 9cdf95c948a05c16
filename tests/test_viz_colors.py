"""The heading colour map: a hue circle of constant lightness and chroma, readable on both themes."""

from __future__ import annotations

import numpy as np
import pytest

from flocking.viz.colors import (DEVIATION_FULL, THEMES, angle_colors, deviation_colors, deviation_parts,
                                 heading_colors, relative_luminance, theme_of_color, wheel_image)
from flocking.viz.local import local_headings


def to_oklab(rgb):
    """sRGB in [0, 1] -> OKLab (Ottosson's published matrices): the inverse of what colors.py does."""
    rgb = np.asarray(rgb, float)
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    lms = linear @ np.array([[0.4122214708, 0.5363325363, 0.0514459929],
                             [0.2119034982, 0.6806995451, 0.1073969566],
                             [0.0883024619, 0.2817188376, 0.6299787005]]).T
    return np.cbrt(lms) @ np.array([[0.2104542553, 0.7936177850, -0.0040720468],
                                    [1.9779984951, -2.4285922050, 0.4505937099],
                                    [0.0259040371, 0.7827717662, -0.8086757660]]).T


def contrast(a, b):
    """WCAG contrast ratio of two colours."""
    la, lb = relative_luminance(a), relative_luminance(b)
    return (np.maximum(la, lb) + 0.05) / (np.minimum(la, lb) + 0.05)


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_every_hue_has_the_same_lightness_and_chroma_so_none_is_clipped(theme):
    t = THEMES[theme]
    angles = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    lab = to_oklab(angle_colors(angles, t))
    assert np.allclose(lab[:, 0], t.lightness, atol=2e-3)          # inside sRGB: nothing clipped
    assert np.allclose(np.hypot(lab[:, 1], lab[:, 2]), t.chroma, atol=2e-3)
    # equal turns, equal steps of colour, across 360 -> 0 too: no jump anywhere
    steps = np.linalg.norm(np.diff(np.vstack([lab, lab[:1]]), axis=0), axis=1)
    assert steps.max() / steps.min() < 1.05
    ink_l, ink_c = t.ink
    lab = to_oklab(angle_colors(angles, t, ink=True))
    assert np.allclose(lab[:, 0], ink_l, atol=2e-3) and np.allclose(np.hypot(lab[:, 1], lab[:, 2]), ink_c, atol=2e-3)


@pytest.mark.parametrize("theme", ["dark", "light"])
def test_every_heading_reads_on_its_background(theme):
    # WCAG asks 3:1 of graphics against their background; pure HSV blue on black is 2.4:1
    # and HSV yellow on white 1.07:1, which is why arrows of those headings vanished
    t = THEMES[theme]
    colours = angle_colors(np.linspace(0, 2 * np.pi, 360, endpoint=False), t)
    assert contrast(colours, np.asarray(t.background)).min() >= 3.0
    assert contrast(np.array([0.0, 0.0, 1.0]), np.zeros(3)) < 3.0  # the old map's blue, for the record


def test_headings_map_to_their_angle_and_3d_tilt_turns_grey():
    t = THEMES["dark"]
    angles = np.radians([0.0, 90.0, 180.0, 270.0])
    heads = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    assert np.allclose(heading_colors(heads, t), angle_colors(angles, t))
    red, green, blue = angle_colors(0.0, t)
    assert red > green and red > blue                                  # +x reads as red
    tilted = heading_colors(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.6, 0.0, 0.8]]), t)
    assert np.allclose(tilted[0], tilted[0].mean()) and np.allclose(tilted[0], tilted[1])  # vertical: grey
    chroma = np.hypot(*to_oklab(tilted[2])[1:])
    assert chroma == pytest.approx(0.6 * t.chroma, abs=2e-3)          # chroma ~ sin(polar angle)


@pytest.mark.parametrize("dim", [2, 3])
def test_wheel_key_shows_the_colour_of_each_direction(dim):
    t = THEMES["light"]
    size = 101
    rgba = wheel_image(size, dim, t)
    for angle in np.radians([0.0, 60.0, 135.0, 250.0]):
        col = int(round(50 + 40 * np.cos(angle)))
        row = int(round(50 - 40 * np.sin(angle)))                     # rows run downward, +y is up
        x, y = (col + 0.5) / size * 2 - 1, 1 - (row + 0.5) / size * 2
        strength = np.hypot(x, y) if dim == 3 else 1.0                # 3D: grey at the centre (vertical)
        assert rgba[row, col, 3] == 1.0
        assert np.allclose(rgba[row, col, :3], angle_colors(np.arctan2(y, x), t, strength))
    assert rgba[0, 0, 3] == 0.0                                        # outside the disc
    assert (rgba[50, 50, 3] == 0.0) == (dim == 2)                      # the ring has a hole, the disc not


def test_theme_follows_the_background_it_is_drawn_on():
    assert theme_of_color("black").name == "dark" and theme_of_color("#f5f5f5").name == "light"
    assert theme_of_color((0.2, 0.2, 0.25)).name == "dark"


def tilted(degrees_off, toward):
    """Unit headings ``degrees_off`` from +x toward the unit vector ``toward`` (perpendicular to x)."""
    a = np.radians(degrees_off)
    return np.cos(a)[:, None] * [1.0, 0.0, 0.0] + np.sin(a)[:, None] * np.asarray(toward, float)


def test_deviation_angle_and_direction_of_constructed_turns():
    # about a mean along +x: turns toward +z are "up" (90 degrees), toward +y and -y opposite sideways
    up, side, down = tilted(np.array([12.0]), [0, 0, 1]), tilted(np.array([5.0]), [0, 1, 0]), \
        tilted(np.array([30.0]), [0, 0, -1])
    headings = np.vstack([up, side, down])
    angle, direction = deviation_parts(headings, mean=[1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.degrees(angle), [12.0, 5.0, 30.0], atol=1e-9)
    np.testing.assert_allclose(np.degrees(direction)[[0, 2]], [90.0, -90.0], atol=1e-9)
    assert abs(abs(np.degrees(direction[1])) - 180.0) < 1e-9 or abs(np.degrees(direction[1])) < 1e-9
    # colours: grey along the mean, the heading circle's colour at full strength from DEVIATION_FULL on
    t = THEMES["light"]
    along = deviation_colors(np.array([[1.0, 0.0, 0.0]]), t, mean=[1.0, 0.0, 0.0])
    np.testing.assert_allclose(along[0], angle_colors(0.0, t, 0.0), atol=1e-12)
    full = tilted(np.array([np.degrees(DEVIATION_FULL), 80.0]), [0, 0, 1])
    np.testing.assert_allclose(deviation_colors(full, t, mean=[1.0, 0.0, 0.0]),
                               angle_colors(np.full(2, np.pi / 2), t), atol=1e-12)
    half = tilted(np.array([np.degrees(DEVIATION_FULL) / 2]), [0, 0, 1])
    np.testing.assert_allclose(deviation_colors(half, t, mean=[1.0, 0.0, 0.0]),
                               angle_colors(np.pi / 2, t, 0.5)[None], atol=1e-12)


def test_deviation_of_a_flock_without_mean_heading_is_zero():
    angle, direction = deviation_parts(np.array([[1.0, 0.0], [-1.0, 0.0]]))
    assert angle.tolist() == [0.0, 0.0] and direction.tolist() == [0.0, 0.0]


@pytest.mark.parametrize("walls", [(True, False), (False, False)])
def test_local_headings_average_over_a_neighbourhood_and_not_across_walls(walls):
    # a strip along each side x = 0 and x = L, heading +y and +x: a wall keeps them apart,
    # a periodic side makes them neighbours, whose local mean points between the two
    rng = np.random.default_rng(4)
    box = (32.0, 32.0)
    x = np.concatenate([rng.uniform(-16, -14, 3000), rng.uniform(14, 16, 3000)])
    positions = np.c_[x, rng.uniform(-16, 16, 6000)]
    own = np.where((x < 0)[:, None], [[0.0, 1.0]], [[1.0, 0.0]])
    local = local_headings(positions, own, box, walls)
    edge = np.abs(np.abs(x) - 16) < 0.3  # the particles right at the box's sides
    agreement = np.einsum("ij,ij->i", local[edge], own[edge])
    if walls[0]:
        assert agreement.min() > 0.999  # each strip keeps its own heading
    else:
        assert 0.6 < agreement.mean() < 0.95  # pulled toward the other strip's, 45 degrees off at most
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), 1.0, atol=1e-12)
