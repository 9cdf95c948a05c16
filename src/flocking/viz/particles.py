"""The particles of a frame on matplotlib axes, in one of three styles, with the box's
walls and obstacles (:class:`FrameArtist`), and the conversion of a frame's centred points
to the box coordinates every picture shows (:func:`box_coordinates`). The styles:

* ``arrows`` (2D): one arrow per particle coloured by heading (matplotlib quiver);
* ``density`` (2D): brightness = density with a colour bar, hue = local mean heading
  where there is local order (:mod:`.density`);
* ``perspective`` (3D): shaded cones along the headings through a perspective camera
  (:mod:`.perspective`), with an axis triad (:mod:`.rulers`).

``auto`` picks arrows while each arrow gets :data:`ARROW_MIN_POINTS` on the page
(about 3e4 particles at the default size), density beyond, and perspective in 3D.

Particles are coloured by heading, or (``color="species"``, the default for a run with
several species) by species, or (``color="deviation"``, the default in 3D) by the angle
between each heading and the flock's mean heading, which shows the structure of an
ordered flock that a colour per heading paints in one hue. Walls are a solid line along
each wall axis' sides (periodic sides keep the plain frame), obstacles solid discs (3D:
shaded spheres) drawn over the particles, in every style and both themes.
"""

from __future__ import annotations

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import style as house
from .colors import choose_color, deviation_colors, get_theme, heading_colors
from .density import DensityField, density_image, density_scale, grid_shape
from .local import local_headings
from .perspective import glyph_length, perspective_image
from .rulers import make_rulers, place_rulers, ruler_zoom


STYLES = ("auto", "arrows", "density", "perspective")

#: ``auto`` draws arrows while the mean spacing between particles is at least this many
#: points (1/72 inch) on the page, whatever the resolution.
ARROW_MIN_POINTS = 2.0


def check_style(style_name: str, dim: int) -> str:
    if style_name not in STYLES:
        raise ParameterError(f"style: must be one of {', '.join(STYLES)} (got {style_name!r})")
    if dim == 3 and style_name in ("arrows", "density"):
        raise ParameterError(f"style: 3D frames are drawn in perspective (got {style_name!r})")
    if dim == 2 and style_name == "perspective":
        raise ParameterError("style: perspective is for 3D frames (got 'perspective')")
    return style_name


def choose_style(style_name: str, dim: int, n: int, box_lengths, points: float) -> str:
    """Resolve ``auto``: perspective in 3D, else arrows if they get room, else density.
    ``points`` is the longer side of the box on the page, in points."""
    style_name = check_style(style_name, dim)
    if style_name != "auto":
        return style_name
    if dim == 3:
        return "perspective"
    lengths = np.asarray(box_lengths, float)[:2]
    spacing = np.sqrt(np.prod(lengths) / max(n, 1)) * points / lengths.max()
    return "arrows" if spacing >= ARROW_MIN_POINTS else "density"


def positive(name: str, value) -> float:
    """``value`` as a finite float > 0, or a :class:`ParameterError` naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (np.isfinite(number) and number > 0):
        raise ParameterError(f"{name}: must be a number > 0 (got {value!r})")
    return number


def box_coordinates(points, box_lengths) -> np.ndarray:
    """Centred points (a frame's, ``[-L/2, L/2)`` per axis, as GSD files hold them) in box
    coordinates, ``[0, L)``: the engine's and the config files'.

    >>> box_coordinates([[-16.0, 0.0], [15.5, -16.0]], (32.0, 32.0)).tolist()
    [[0.0, 16.0], [31.5, 0.0]]
    """
    box = np.asarray(box_lengths, dtype=float)
    return np.asarray(points, dtype=float)[..., : len(box)] + box / 2


def frame_density(frame, pixels: int) -> DensityField:
    """The :class:`DensityField` of a 2D frame, its longer side ``pixels`` bins, with its
    walls, obstacles and species."""
    box = frame.box_lengths
    return DensityField(frame.positions, frame.headings, box, grid_shape(box, pixels), walls=frame.walls,
                        obstacles=Space.of_frame(frame).obstacle_images(), typeid=frame.typeid,
                        types=len(frame.types))


class FrameArtist:
    """The particles of one frame on a matplotlib axes; :meth:`update` redraws them in place.

    It changes nothing outside the axes (it sets their limits, aspect and, for images,
    background). Colours come from :meth:`colors`: the heading, each particle's species
    (``species``), or the angle to the mean heading (``deviation``); ``auto`` is species
    if the frame has several, else deviation in 3D and heading in 2D. The frame's walls
    and obstacles are drawn with it; a 3D view (``rulers``) ticks three edges of the box
    in box coordinates. ``density_max`` fixes the top of the density scale (default:
    from the first frame).
    """

    def __init__(self, ax, frame, theme="dark", style="auto", arrow_scale=1.0, pixels=None,
                 azim=-60.0, elev=25.0, density_max=None, rulers=True, color="auto"):
        self.ax = ax
        self.theme = get_theme(theme)
        self.dim = frame.dim
        self.box = np.asarray(frame.box_lengths, dtype=float)
        bbox = ax.get_window_extent()
        if pixels is None:
            pixels = max(bbox.width, bbox.height)
        self.pixels = max(int(pixels), 16)
        points = max(bbox.width, bbox.height) * 72.0 / ax.figure.dpi
        self.style = choose_style(style, frame.dim, frame.n, self.box, points)
        self.color = choose_color(color, frame.types, frame.dim)
        self.types = frame.types
        self.walls = tuple(frame.walls)
        self.obstacles = Space.of_frame(frame).obstacle_images()
        self.arrow_scale = positive("arrow_scale", arrow_scale)
        self.azim, self.elev = float(azim), float(elev)
        self.density_max = None if density_max is None else positive("density_max", density_max)
        if self.dim == 2:
            lx, ly = self.box[:2]
            ax.set_xlim(0.0, lx)
            ax.set_ylim(0.0, ly)
            ax.set_aspect("equal")
        if self.style == "perspective":
            ax.set_facecolor(self.theme.background)
            ax.set_axis_off()
        elif self.style == "density":
            ax.set_facecolor(self.theme.background)
        self._artist = None
        self.rulers = make_rulers(ax, self.box, self.theme) if self.style == "perspective" and rulers else None
        self.zoom = ruler_zoom(points, house.fontsize(ax.figure)) if self.rulers else 1.0
        self.boundaries = self._boundaries() if self.dim == 2 else []
        self.update(frame)

    def colors(self, frame) -> np.ndarray:
        """``(N, 3)`` RGB of the particles: their headings', their species' or their
        deviations' from the mean heading colours."""
        if self.color == "species":
            return house.species_colors(len(self.types), self.theme)[frame.typeid]
        if self.color == "deviation":
            local = local_headings(frame.positions, frame.headings, self.box, self.walls)
            return deviation_colors(local, self.theme, mean=frame.headings.sum(axis=0))
        return heading_colors(frame.headings, self.theme)

    def legend_handles(self) -> list:
        """One legend entry per species (none when colouring by heading)."""
        from matplotlib.lines import Line2D

        if self.color != "species":
            return []
        return [Line2D([], [], ls="none", marker="s", color=tuple(c), label=name)
                for name, c in zip(self.types, house.species_colors(len(self.types), self.theme))]

    def _boundaries(self) -> list:
        """Wall lines (a side of each wall axis) and obstacle discs above the particles (2D)."""
        from matplotlib.collections import PatchCollection
        from matplotlib.patches import Circle

        t, ax = self.theme, self.ax
        width = 0.25 * house.fontsize(ax.figure)  # points: reads at every size
        lx, ly = self.box[:2]
        artists = []
        if len(self.obstacles):
            centres = box_coordinates(self.obstacles[:, :2], self.box)
            discs = PatchCollection([Circle(c, row[2]) for c, row in zip(centres, self.obstacles)],
                                    facecolor=t.obstacle, edgecolor=t.text, linewidth=0.4 * width, zorder=4)
            artists.append(ax.add_collection(discs))
        sides = {0: ([0, 0], [0, ly], [lx, lx], [0, ly]), 1: ([0, lx], [0, 0], [0, lx], [ly, ly])}
        for axis, wall in enumerate(self.walls):
            if wall:
                x0, y0, x1, y1 = sides[axis]
                for xs, ys in ((x0, y0), (x1, y1)):
                    artists += ax.plot(xs, ys, color=t.text, lw=width, solid_capstyle="projecting", clip_on=False,
                                       zorder=5)
        return artists

    @property
    def arrow_length(self) -> float:
        spacing = np.sqrt(np.prod(self.box[:2]) / max(self._n, 1))
        return 0.9 * spacing * self.arrow_scale

    def update(self, frame, azim: float | None = None) -> None:
        self._n = frame.n
        if azim is not None:
            self.azim = float(azim)
        if self.style == "arrows":
            self._arrows(frame)
        elif self.style == "density":
            self._density(frame)
        else:
            self._perspective(frame)

    def _arrows(self, frame) -> None:
        heads = frame.headings
        length = self.arrow_length
        colors = self.colors(frame)
        uv = heads * length
        xy = box_coordinates(frame.positions, self.box)
        if self._artist is None or len(self._artist.U) != frame.n:
            if self._artist is not None:
                self._artist.remove()
            self._artist = self.ax.quiver(
                xy[:, 0], xy[:, 1], uv[:, 0], uv[:, 1], color=colors,
                angles="xy", scale_units="xy", scale=1.0, units="xy", width=0.16 * length,
                headwidth=3.0, headlength=3.2, headaxislength=2.8, pivot="middle", minlength=0.0,
                linewidth=0)
        else:
            self._artist.set_offsets(xy)
            self._artist.set_UVC(uv[:, 0], uv[:, 1])
            self._artist.set_facecolor(colors)

    def density_field(self, frame) -> DensityField:
        return frame_density(frame, self.pixels)

    def _density(self, frame) -> None:
        field = self.density_field(frame)
        if self.density_max is None:
            self.density_max = density_scale([field])
        species = house.species_colors(len(self.types), self.theme) if self.color == "species" else None
        self._show(density_image(field, self.theme, self.density_max, species), "bilinear")

    def _perspective(self, frame) -> None:
        rgb = perspective_image(frame.points, frame.headings, self.box, self.pixels, self.theme,
                                azim=self.azim, elev=self.elev,
                                length=glyph_length(frame.n, self.box, self.arrow_scale),
                                colors=self.colors(frame), walls=self.walls, obstacles=self.obstacles,
                                zoom=self.zoom)
        self._show(rgb, "antialiased")
        if self.rulers is not None:
            place_rulers(self.rulers, self.ax, self.box, self.pixels, self.azim, self.elev, self.zoom)

    def _show(self, rgb, interpolation) -> None:
        rgb = np.clip(rgb, 0.0, 1.0)
        if self._artist is None or self._artist.get_array().shape != rgb.shape:
            if self._artist is not None:
                self._artist.remove()
            extent = None
            if self.dim == 2:
                lx, ly = self.box[:2]
                extent = (0.0, lx, 0.0, ly)
            self._artist = self.ax.imshow(rgb, extent=extent, interpolation=interpolation, zorder=0)
        else:
            self._artist.set_data(rgb)
