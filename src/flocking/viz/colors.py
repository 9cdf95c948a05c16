"""Colours: themes, the heading -> colour map, the colour-wheel key, and the species'
colours.

A heading's colour is its angle on a hue circle of constant lightness and chroma in
OKLab, a perceptually uniform colour space: equal turns look like equal changes of
colour, no hue stands out or vanishes (pure blue on black does in HSV), and every hue
has the same contrast against the background. The circle is cyclic, so a flock turning
through 360 degrees never jumps: 0 = +x is red, 90 degrees = +y olive green, 180 =
teal, 270 = violet. The dark theme uses a lighter circle than the light theme, so the
colours read on black and on white alike.

In 3D the hue is the azimuth in the xy plane and the colour turns grey (the same
lightness, no chroma) as the heading tilts toward +-z, so the key is a disc whose
grey centre means "vertical".

An ordered flock has nearly one heading, so it takes nearly one colour. Its structure
shows in how the local mean heading turns off the flock's mean heading
(:func:`deviation_colors`): on the same disc as 3D's key, grey along the mean, the hue
for the direction of the turn.

Species take the house palette's colours in order (:func:`.style.species_colors`);
:func:`choose_color` picks them by default for a frame with several species.

>>> rgb = heading_colors(np.array([[1.0, 0.0], [-1.0, 0.0]]), THEMES["dark"])
>>> rgb.round(2).tolist()
[[0.94, 0.54, 0.49], [0.08, 0.75, 0.84]]
>>> [round(float(relative_luminance(c)), 2) for c in rgb]   # equal lightness, not equal RGB
[0.38, 0.43]
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..checks import ParameterError

#: What particles can be coloured by: ``auto`` is ``species`` for a frame with several
#: species, else ``deviation`` (the angle to the mean heading) in 3D and ``heading`` in 2D.
COLORS = ("auto", "heading", "species", "deviation")


@dataclasses.dataclass(frozen=True)
class Theme:
    """Colours of one look: figure and box background, text, box edges, and the
    lightness and chroma (OKLab) of the particles' colours."""

    name: str
    figure: tuple
    background: tuple
    text: tuple
    edge: tuple
    lightness: float  # OKLab L of particle colours: far from the background's
    chroma: float  # OKLab chroma of a fully ordered heading, inside sRGB at every hue
    ink: tuple = (0.74, 0.125)  # (L, chroma) of the densest regions of a density map
    obstacle: tuple = (0.3, 0.3, 0.3)  # fill of obstacles (their outline and walls: ``text``)


def _hex(code: str) -> tuple:
    return tuple(int(code[i:i + 2], 16) / 255 for i in (1, 3, 5))


THEMES = {
    "dark": Theme("dark", _hex("#0b0e14"), _hex("#000000"), _hex("#e6e6e6"), _hex("#5a6270"), 0.74, 0.125,
                  (0.74, 0.125), _hex("#3a404c")),
    "light": Theme("light", _hex("#ffffff"), _hex("#fbfbf8"), _hex("#1a1a1a"), _hex("#9a9a9a"), 0.58, 0.098,
                   (0.45, 0.076), _hex("#c8ccd3")),
}

#: OKLab hue (radians) of heading 0 (+x): the hue of sRGB red, so +x reads as red.
HUE_OFFSET = np.radians(29.2)


def get_theme(theme) -> Theme:
    """A :class:`Theme` from its name (``dark`` or ``light``) or the theme itself."""
    from ..model import ParameterError

    if isinstance(theme, Theme):
        return theme
    if theme not in THEMES:
        raise ParameterError(f"theme: must be one of {', '.join(THEMES)} (got {theme!r})")
    return THEMES[theme]


def theme_of_color(color) -> Theme:
    """The theme whose background suits ``color`` (any matplotlib colour): dark below
    half luminance, light above."""
    from matplotlib.colors import to_rgb

    return THEMES["dark" if relative_luminance(np.asarray(to_rgb(color))) < 0.5 else "light"]


def relative_luminance(rgb) -> np.ndarray:
    """WCAG relative luminance of sRGB colours in [0, 1] (last axis: R, G, B)."""
    return _linear(np.asarray(rgb, float)) @ np.array([0.2126, 0.7152, 0.0722])


def _linear(srgb: np.ndarray) -> np.ndarray:
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def _encode(linear: np.ndarray) -> np.ndarray:
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def oklab_to_rgb(lightness, a, b) -> np.ndarray:
    """sRGB in [0, 1], shape ``(..., 3)``, of OKLab colours (arguments broadcast;
    colours outside sRGB are clipped)."""
    L, a, b = np.broadcast_arrays(np.asarray(lightness, float), np.asarray(a, float), np.asarray(b, float))
    l_ = (L + 0.3963377774 * a + 0.2158037573 * b) ** 3
    m_ = (L - 0.1055613458 * a - 0.0638541728 * b) ** 3
    s_ = (L - 0.0894841775 * a - 1.2914855480 * b) ** 3
    rgb = np.stack([4.0767416621 * l_ - 3.3077115913 * m_ + 0.2309699292 * s_,
                    -1.2684380046 * l_ + 2.6097574011 * m_ - 0.3413193965 * s_,
                    -0.0041960863 * l_ - 0.7034186147 * m_ + 1.7076147010 * s_], axis=-1)
    return _encode(rgb)


def angle_colors(angle, theme: Theme, strength=1.0, ink: bool = False) -> np.ndarray:
    """RGB of heading angles (radians, from +x toward +y): ``strength`` in [0, 1] scales
    the chroma, 0 giving the grey of the same lightness; ``ink``: the theme's density-map
    lightness and chroma instead of its particles'. Arguments broadcast."""
    t = get_theme(theme)
    lightness, chroma = t.ink if ink else (t.lightness, t.chroma)
    hue = np.asarray(angle, float) + HUE_OFFSET
    chroma = chroma * np.clip(strength, 0.0, 1.0)
    return oklab_to_rgb(lightness, chroma * np.cos(hue), chroma * np.sin(hue))


def heading_colors(headings: np.ndarray, theme: Theme) -> np.ndarray:
    """``(N, 3)`` RGB in [0, 1] for ``(N, d)`` unit headings (3D: grey toward +-z)."""
    headings = np.asarray(headings, dtype=float)
    strength = 1.0
    if headings.shape[1] == 3:
        strength = np.sqrt(np.clip(1.0 - headings[:, 2] ** 2, 0.0, 1.0))
    return angle_colors(np.arctan2(headings[:, 1], headings[:, 0]), theme, strength)


def wheel_image(size: int, dim: int, theme: Theme, ink: bool = False) -> np.ndarray:
    """RGBA key, ``size`` pixels square: a hue ring (2D) or a disc grey at its centre (3D),
    in the colours of particles or (``ink``) of density maps.

    Pixel (row, column) follows image conventions, rows downward, so +y is up.
    """
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c, -c)
    r = np.hypot(x, y)
    inner = 0.0 if dim == 3 else 0.55
    rgba = np.zeros((size, size, 4))
    rgba[..., :3] = angle_colors(np.arctan2(y, x), theme, np.clip(r, 0, 1) if dim == 3 else 1.0, ink)
    edge = 2.0 / size  # one pixel of soft (anti-aliased) rim
    alpha = np.clip((1.0 - r) / edge, 0, 1)
    if inner:
        alpha = np.minimum(alpha, np.clip((r - inner) / edge, 0, 1))
    rgba[..., 3] = alpha
    return rgba


#: The angle to the mean heading (radians) at which a deviation's colour is full (a
#: local mean heading's: :mod:`.local`).
DEVIATION_FULL = np.radians(10.0)


def deviation_parts(headings: np.ndarray, mean=None) -> tuple[np.ndarray, np.ndarray]:
    """``(angle, direction)`` of each of ``(N, d)`` unit headings off the mean heading
    ``m`` (``mean``, default theirs): the angle between them (radians, in [0, pi]), and
    the direction of the turn (radians), seen along ``m`` with "up" at 90 degrees: +z
    made perpendicular to ``m`` in 3D (+x when ``m`` is vertical), ``m`` turned a
    quarter counter-clockwise in 2D. A zero mean leaves every angle and direction 0.

    >>> angle, direction = deviation_parts(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 0.0]]))
    >>> np.degrees(angle).round(1).tolist(), np.degrees(direction).round(1).tolist()
    ([26.6, 63.4, 26.6], [-90.0, 90.0, -90.0])
    """
    u = np.asarray(headings, dtype=float)
    n, dim = u.shape
    mean = u.sum(axis=0) if mean is None else np.asarray(mean, dtype=float)
    norm = np.linalg.norm(mean)
    if n == 0 or norm == 0:
        return np.zeros(n), np.zeros(n)
    m = mean / norm
    if dim == 2:
        up, right = np.array([-m[1], m[0]]), m  # the second only breaks ties: a turn is up or down
    else:
        z = np.array([0.0, 0.0, 1.0]) if abs(m[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
        up = z - (z @ m) * m
        up /= np.linalg.norm(up)
        right = np.cross(up, m)
    along = u @ m
    across_up, across_right = u @ up, (u @ right if dim == 3 else np.zeros(n))
    return np.arctan2(np.hypot(across_up, across_right), along), np.arctan2(across_up, across_right)


def deviation_colors(headings: np.ndarray, theme: Theme, mean=None) -> np.ndarray:
    """``(N, 3)`` RGB of ``(N, d)`` unit headings by how they turn off the mean heading
    (:func:`deviation_parts`): the hue of the direction of the turn, on the heading
    circle, with a chroma that grows from grey (along the mean) to full at
    :data:`DEVIATION_FULL`. Given the local mean headings (:mod:`.local`), regions that
    turn alike share a colour: the correlated fluctuations of an ordered flock."""
    angle, direction = deviation_parts(headings, mean)
    return angle_colors(direction, theme, np.clip(angle / DEVIATION_FULL, 0.0, 1.0))


def check_color(color: str) -> str:
    """``color`` if it is one of :data:`COLORS`, else a one-line error naming it."""
    if color not in COLORS:
        raise ParameterError(f"color: must be one of {', '.join(COLORS)} (got {color!r})")
    return color


def choose_color(color: str, types, dim: int = 2) -> str:
    """Resolve ``auto`` for a ``dim``-dimensional frame whose species are named ``types``.

    >>> choose_color("auto", ("A",), 2), choose_color("auto", ("A",), 3), choose_color("auto", ("A", "B"), 3)
    ('heading', 'deviation', 'species')
    """
    color = check_color(color)
    if color == "auto":
        return "species" if len(types) > 1 else ("deviation" if dim == 3 else "heading")
    return color
