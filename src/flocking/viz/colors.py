"""Colours: themes, the heading -> colour map, and the colour-wheel key.

A heading's colour is its angle on the HSV hue circle (0 = +x red, 90 degrees = +y
yellow-green, 180 = cyan, 270 = violet): cyclic, so a flock turning through 360 degrees
never jumps. In 3D the hue is the azimuth in the xy plane and the colour pales as the
heading tilts toward +-z, so the key is a disc whose centre means "vertical".

>>> rgb = heading_colors(np.array([[1.0, 0.0], [-1.0, 0.0]]), THEMES["dark"])
>>> rgb.round(2).tolist()
[[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Theme:
    """Colours of one look: figure and box background, text, box edges, particle brightness."""

    name: str
    figure: tuple
    background: tuple
    text: tuple
    edge: tuple
    value: float  # HSV value of particle colours (slightly darker on white)


def _hex(code: str) -> tuple:
    return tuple(int(code[i:i + 2], 16) / 255 for i in (1, 3, 5))


THEMES = {
    "dark": Theme("dark", _hex("#0b0e14"), _hex("#000000"), _hex("#e6e6e6"), _hex("#5a6270"), 1.0),
    "light": Theme("light", _hex("#ffffff"), _hex("#fbfbf8"), _hex("#1a1a1a"), _hex("#9a9a9a"), 0.85),
}


def get_theme(theme) -> Theme:
    """A :class:`Theme` from its name (``dark`` or ``light``) or the theme itself."""
    from ..model import ParameterError

    if isinstance(theme, Theme):
        return theme
    if theme not in THEMES:
        raise ParameterError(f"theme: must be one of {', '.join(THEMES)} (got {theme!r})")
    return THEMES[theme]


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV -> RGB, all arguments broadcast, hue in turns; shape ``(..., 3)``."""
    h, s, v = np.broadcast_arrays(np.asarray(h, float) % 1.0, np.asarray(s, float), np.asarray(v, float))
    k = (np.array([5.0, 3.0, 1.0]) + 6.0 * h[..., None]) % 6.0
    return v[..., None] - (v * s)[..., None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def heading_hue(headings: np.ndarray) -> np.ndarray:
    """Hue in turns ``[0, 1)`` of each heading's angle in the xy plane."""
    headings = np.asarray(headings, dtype=float)
    return (np.arctan2(headings[:, 1], headings[:, 0]) / (2 * np.pi)) % 1.0


def heading_colors(headings: np.ndarray, theme: Theme) -> np.ndarray:
    """``(N, 3)`` RGB in [0, 1] for ``(N, d)`` unit headings (3D: white toward +-z)."""
    headings = np.asarray(headings, dtype=float)
    saturation = 1.0
    if headings.shape[1] == 3:
        saturation = np.sqrt(np.clip(1.0 - headings[:, 2] ** 2, 0.0, 1.0)) * 0.85 + 0.15
    return hsv_to_rgb(heading_hue(headings), saturation, theme.value)


def wheel_image(size: int, dim: int, theme: Theme) -> np.ndarray:
    """RGBA key, ``size`` pixels square: a hue ring (2D) or a disc white at its centre (3D).

    Pixel (row, column) follows image conventions, rows downward, so +y is up.
    """
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c, -c)
    r = np.hypot(x, y)
    hue = (np.arctan2(y, x) / (2 * np.pi)) % 1.0
    if dim == 3:
        inside = r <= 1.0
        saturation = np.clip(r, 0, 1) * 0.85 + 0.15
    else:
        inside = (r <= 1.0) & (r >= 0.55)
        saturation = np.ones_like(r)
    rgba = np.zeros((size, size, 4))
    rgba[..., :3] = hsv_to_rgb(hue, saturation, theme.value)
    # soft (anti-aliased) rim: one pixel of falloff
    edge = 1.0 / size * 2
    alpha = np.clip((1.0 - r) / edge, 0, 1)
    if dim == 2:
        alpha = np.minimum(alpha, np.clip((r - 0.55) / edge, 0, 1))
    rgba[..., 3] = np.where(inside | (alpha > 0), alpha, 0.0)
    return rgba
