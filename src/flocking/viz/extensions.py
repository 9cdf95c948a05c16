"""What a picture shows beyond the particles' headings: species colours, walls, obstacles.

* Species take the house palette's colours in order (:func:`.style.palette`, qualitative,
  chosen to read on both themes), and :func:`choose_color` picks them by default for a
  run with several species.
* Obstacles on periodic axes wrap around the box like the particles do:
  :func:`obstacle_images` gives every copy that reaches into the box.

>>> from flocking.viz.colors import THEMES
>>> species_colors(2, THEMES["light"]).round(3).tolist()
[[0.122, 0.373, 0.659], [0.82, 0.286, 0.357]]
>>> obstacle_images(np.array([[4.5, 0.0, 1.0]]), (10.0, 10.0), (False, True)).tolist()
[[-5.5, 0.0, 1.0], [4.5, 0.0, 1.0]]
"""

from __future__ import annotations

import numpy as np

from ..model import ParameterError
from ..space import Space
from .colors import Theme, get_theme

#: What particles can be coloured by: ``auto`` is ``species`` for a frame with several
#: species, else ``deviation`` (the angle to the mean heading) in 3D and ``heading`` in 2D.
COLORS = ("auto", "heading", "species", "deviation")


def check_color(color: str) -> str:
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


def species_colors(count: int, theme: Theme) -> np.ndarray:
    """``(count, 3)`` RGB of ``count`` species: the palette's colours, in turn."""
    from matplotlib.colors import to_rgb

    from .style import palette

    colours = palette(get_theme(theme))
    return np.array([to_rgb(colours[s % len(colours)]) for s in range(count)]).reshape(-1, 3)


def obstacle_images(obstacles: np.ndarray, box_lengths, walls) -> np.ndarray:
    """Rows ``(centre..., radius)`` of every copy of the obstacles (centred coordinates)
    that reaches into the box (:meth:`flocking.space.Space.obstacle_images`)."""
    box = np.asarray(box_lengths, float)
    return Space(tuple(box), tuple(walls), obstacles, tuple(-box / 2)).obstacle_images()


def free_mask(obstacles: np.ndarray, box_lengths, shape) -> np.ndarray:
    """``shape = (rows, columns)`` booleans of a 2D grid (rows downward): whether each
    bin's centre lies outside every obstacle (``obstacles`` already with their images, so
    no further image is taken: :meth:`flocking.space.Space.in_obstacle` with walls)."""
    ny, nx = shape
    lx, ly = float(box_lengths[0]), float(box_lengths[1])
    x = ((np.arange(nx) + 0.5) / nx - 0.5) * lx
    y = (0.5 - (np.arange(ny) + 0.5) / ny) * ly
    centres = np.stack(np.broadcast_arrays(x[None, :], y[:, None]), axis=-1)
    space = Space((lx, ly), (True, True), np.asarray(obstacles, float).reshape(-1, 3), (-lx / 2, -ly / 2))
    return ~space.in_obstacle(centres)
