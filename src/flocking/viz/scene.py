"""Frames as pictures: one matplotlib figure built once, whose artists each frame updates.

A :class:`Scene` lays out the box, a title with the run's parameters (:mod:`.caption`), a
time label, the colour key (:mod:`.keys`) and (density maps) a colour bar, in the house
style of :mod:`.style`, on an Agg canvas (no display needed). Its layout is settled once,
so ``scene.draw(frame)`` only updates artists (a :class:`.particles.FrameArtist`) and
``scene.rgb()`` returns the pixels: a movie costs one redraw a frame, never a new figure.
The styles and colourings are :mod:`.particles`'.

Pictures show box coordinates, each axis from 0 to L in units of the interaction
radius R, as the engine and the config files use them (a frame's points are centred,
as GSD files store them: :func:`.particles.box_coordinates` converts). The step and the
polar order are read out under the key, beside the box, not over the particles.

>>> import flocking
>>> frame = flocking.Frame(0, 2, [4, 4], np.zeros((1, 3)), np.array([[0.5, 0, 0]]))
>>> scene = Scene.for_frame(frame, size=3.0, dpi=64)
>>> rgb = scene.draw(frame).rgb()
>>> rgb.shape[1], rgb.shape == (scene.pixels[1], scene.pixels[0], 3)
(192, True)
>>> [float(x) for x in scene.ax.get_xlim()], scene.ax.get_xlabel()   # box coordinates, 0 to L
([0.0, 4.0], '$x$ (units of $R$)')
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from . import style as house
from .caption import as_parameters, describe, readout_lines, time_text
from .colors import check_color, choose_color, get_theme, theme_of_color
from .density import GAMMA, DensityField, density_colormap, density_ticks
from .keys import deviation_key, heading_key, species_key
from .particles import FrameArtist, check_style, choose_style, frame_density, positive


class Scene:
    """A whole picture: box, title, time label, heading key and density colour bar,
    on its own Agg canvas (or through pyplot, so a notebook shows it).

    ``size`` is a name of :data:`.style.SIZES` (``column``, ``page``, ``slide``), a width
    in inches (the height follows the box) or ``(width, height)``; ``dpi`` its pixels
    per inch. The pixel size is rounded to a multiple of 16 so that H.264 takes it as
    it is; ``scene.pixels`` is ``(width, height)``. ``types`` are the species' names
    (:meth:`for_frame` reads them from the frame): with ``color`` ``species`` (or
    ``auto`` and several species) the key names them instead of showing the heading wheel.
    """

    def __init__(self, dim, n, box_lengths, parameters=None, theme="dark", style="auto", size=6.0,
                 dpi=120, arrow_scale=1.0, time_label=True, azim=-60.0, elev=25.0, pyplot=False,
                 density_max=None, title=True, color="auto", types=("A",)):
        self.theme = t = get_theme(theme)
        check_style(style, dim)
        self.color = choose_color(color, types, dim)
        self.types = tuple(types)
        dpi = house.check_dpi(dpi) or house.DPI
        width, height, fs = house.resolve_size(size)
        if isinstance(size, str) and size != "slide":  # a paper's width; the height follows the box
            height = None
        positive("arrow_scale", arrow_scale)
        if density_max is not None:
            density_max = positive("density_max", density_max)
        self.dim = dim
        self.box = np.asarray(box_lengths, dtype=float)[:dim]
        aspect = float(np.clip(self.box[1] / self.box[0], 0.25, 4.0)) if dim == 2 else 1.0
        auto_height = height is None
        width_px = 16 * max(4, round(width * dpi / 16))
        self.figure = house.new_figure(width_px / dpi, height or width, t, fs, dpi, pyplot)
        bands = self._add_title(parameters, n, fs) if title else self._bands(fs, 2.2)
        if auto_height:  # at most: the box takes about 70 % of the width
            height = 0.7 * width * aspect + bands
        height_px = 16 * max(4, round(height * dpi / 16))
        self.pixels = (width_px, height_px)
        self.figure.set_size_inches(width_px / dpi, height_px / dpi)
        points = 72 * min(0.7 * width, (height - bands) / aspect) * max(1.0, aspect)  # the box's longer side
        self.style = choose_style(style, dim, n, self.box, points)
        side = self._add_axes(width, fs)
        self._style_axes(fs)
        self._add_key(parameters, fs, time_label)
        self.colorbar = self._add_colorbar(side, fs, density_max) if side is not None else None
        self._settle(auto_height, dpi)
        bbox = self.ax.get_window_extent()
        self._args = dict(theme=t, style=self.style, arrow_scale=arrow_scale, azim=azim, elev=elev,
                          pixels=int(round(max(bbox.width, bbox.height))), density_max=density_max,
                          color=self.color)
        self.artist = None

    @staticmethod
    def _bands(fs: float, lines: float) -> float:
        """Inches of ``lines`` lines of the base font ``fs``: the title, caption and x label."""
        return lines * fs / 72 * 1.35 + 0.15

    def _add_title(self, parameters, n: int, fs: float) -> float:
        """The title and caption (:func:`.caption.describe`); returns the inches they and
        the x label take (:meth:`_bands`)."""
        fig = self.figure
        lines = 2.2  # the x label and its ticks, in lines of the base font
        main, details = describe(parameters, self.dim, n, self.box)
        house.title(fig, main, details)
        lines += 1.1 * (fig._suptitle.get_text().count("\n") + 1)
        if details:
            lines += 0.88 * (fig._supxlabel.get_text().count("\n") + 1)
        return self._bands(fs, lines)

    def _add_axes(self, width: float, fs: float):
        """The box's axes and, beside them, the key's; returns the side's grid whose lower
        cell takes the density's colour bar (``None`` for other styles)."""
        fig = self.figure
        key_width = max(0.16 * width, 9.0 * fs / 72)  # inches: the wheel and its labels at any size
        grid = fig.add_gridspec(1, 2, width_ratios=[width - key_width, key_width])
        self.ax = fig.add_subplot(grid[0, 0])
        side = None
        if self.style == "density":  # the key with the readout above, the density's colour bar below
            side = grid[0, 1].subgridspec(2, 1, height_ratios=[1.8, 1.6])
            self.key_axes = fig.add_subplot(side[0])
        else:  # the key with the readout, in the middle of the box's height
            self.key_axes = fig.add_subplot(grid[0, 1])
        # a box narrower than its slot (a wide figure) sits next to its keys, not apart
        self.ax.set_anchor("E")
        self.key_axes.set_anchor("W")
        return side

    def _add_key(self, parameters, fs: float, time_label: bool) -> None:
        """The key of the colours (:mod:`.keys`) and the readout under it."""
        t = self.theme
        model = (as_parameters(parameters) or {}).get("model", {})
        self.dt = model.get("dt", 1.0)
        self.nematic = model.get("alignment_rule") == "nematic"
        lines = readout_lines(self.types, self.dt, self.nematic) if time_label else 0
        if self.color == "species":
            self._key_label, self.time_label = species_key(self.key_axes, self.types, t, fs, lines)
        elif self.color == "deviation":
            self._key_label, self.time_label = deviation_key(self.key_axes, self.dim, t, fs, lines)
        else:
            self._key_label, self.time_label = heading_key(self.key_axes, self.dim, t, fs, self.style == "density",
                                                           lines)

    def _add_colorbar(self, side, fs: float, density_max: float | None):
        """The density's colour bar, in the lower cell of ``side``."""
        from matplotlib import colors as mcolors
        from matplotlib.cm import ScalarMappable

        fig, t = self.figure, self.theme
        cax = side[1].subgridspec(1, 3, width_ratios=[1, 0.5, 1])[0, 1]
        cax = fig.add_subplot(cax)
        cax.set_anchor("W")
        self._density_norm = mcolors.PowerNorm(GAMMA, vmin=0.0, vmax=density_max or 1.0)
        mappable = ScalarMappable(norm=self._density_norm, cmap=density_colormap(t))
        colorbar = fig.colorbar(mappable, cax=cax)
        colorbar.set_label(house.LABELS["density"], color=t.text, fontsize=0.9 * fs)
        cax.tick_params(colors=t.text, labelsize=0.8 * fs)
        colorbar.outline.set_edgecolor(t.edge)
        return colorbar

    def _settle(self, auto_height: bool, dpi: float) -> None:
        """Settle the layout once, with the box's axes at their final size (and, if the
        height follows the box, :meth:`_fit_height`); then freeze it and centre it."""
        if self.dim == 2:
            self.ax.set_xlim(0.0, self.box[0])
            self.ax.set_ylim(0.0, self.box[1])
        self.ax.set_aspect("equal")
        self._layout()
        if auto_height:
            self._fit_height(dpi)
        self.figure.set_layout_engine("none")
        self._centre()

    def _fit_height(self, dpi: float) -> None:
        """The height that fits the box's aspect: give back what it leaves empty, or add
        what it lacks when a shorter figure's layout made it narrower than its slot; the
        layout of a shorter figure can move the margins, so the height is bracketed and
        halved."""
        width_px, height_px = self.pixels
        short, tall = 0, None
        for _ in range(10):
            self.ax.apply_aspect()
            slot, shown = self.ax.get_position(original=True), self.ax.get_position()
            spare = (slot.height - shown.height) * height_px
            lacking = (slot.width - shown.width) * width_px * self.box[1] / self.box[0] if self.dim == 2 else 0.0
            if spare >= 16:
                tall = height_px
                guess = height_px - 16 * int(spare // 16)
            elif lacking >= 16:
                short = height_px
                guess = height_px + 16 * int(np.ceil(lacking / 16))
            else:
                break
            if tall is not None and not short < guess < tall:
                guess = 16 * round((short + tall) / 32)
            if tall is not None and tall - short <= 16 or guess in (short, tall):
                guess = tall  # nothing between: the taller, which leaves the box whole
            if guess == height_px:
                break
            height_px = guess
            self.pixels = (width_px, height_px)
            self.figure.set_size_inches(width_px / dpi, height_px / dpi)
            self._layout()

    def _centre(self) -> None:
        """Move the box and its keys, with their labels, together to the middle of the figure."""
        fig = self.figure
        for ax in fig.axes:
            ax.apply_aspect()
        get_renderer = getattr(fig.canvas, "get_renderer", None)
        if get_renderer is None:  # a canvas that cannot measure text
            return
        renderer = get_renderer()
        boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
        left, right = min(b.x0 for b in boxes), max(b.x1 for b in boxes)
        shift = ((fig.bbox.width - right) - left) / 2 / fig.bbox.width  # figure fraction
        # a small shift is left alone, unless a label would be cut at an edge without it
        if abs(shift) > 0.005 or left < 0 or right > fig.bbox.width:
            for ax in fig.axes:
                p = ax.get_position()
                ax.set_position([p.x0 + shift, p.y0, p.width, p.height])

    def _layout(self) -> None:
        with warnings.catch_warnings():  # a tiny figure keeps the grid's plain layout
            warnings.filterwarnings("ignore", "constrained_layout not applied")
            for _ in range(2):  # the second pass starts from the first's margins, and settles
                self.figure.get_layout_engine().execute(self.figure)

    @classmethod
    def for_frame(cls, frame, parameters=None, **options) -> Scene:
        return cls(frame.dim, frame.n, frame.box_lengths, parameters, types=frame.types, **options)

    @classmethod
    def for_trajectory(cls, traj, **options) -> Scene:
        return cls.for_frame(traj[0], traj.parameters, **options)

    def _style_axes(self, fs: float) -> None:
        ax, t = self.ax, self.theme
        house.style_axes(ax, t)
        ax.grid(False)
        if self.dim == 3:
            ax.set_axis_off()
            return
        house.label_axes(ax, "x", "y")
        ax.set_facecolor(t.background)

    @property
    def density_max(self) -> float | None:
        """Top of the density scale (density maps; ``None`` until set or drawn)."""
        return self._args["density_max"]

    def set_density_max(self, value: float) -> None:
        """Fix the top of the density scale, for the colour bar and every frame after."""
        self._args["density_max"] = value
        if self.artist is not None:
            self.artist.density_max = value
        if self.colorbar is not None:
            self._density_norm.vmax = value
            self.colorbar.update_normal(self.colorbar.mappable)
            self.colorbar.set_ticks(density_ticks(value))

    def density_field(self, frame) -> DensityField:
        """The :class:`DensityField` of ``frame`` on this scene's grid."""
        return frame_density(frame, self._args["pixels"])

    def draw(self, frame, azim: float | None = None) -> Scene:
        if self.artist is None:
            self.artist = FrameArtist(self.ax, frame, **self._args)
            if self.artist.style == "density":
                self.set_density_max(self.artist.density_max)
        else:
            self.artist.update(frame, azim=azim)
        if self.time_label is not None:
            self.time_label.set_text(time_text(frame, self.dt, self.nematic))
        return self

    def rgb(self) -> np.ndarray:
        """The picture as an ``(H, W, 3)`` uint8 array."""
        self.figure.canvas.draw()
        return np.asarray(self.figure.canvas.buffer_rgba())[..., :3].copy()

    def save(self, path: str | os.PathLike) -> str:
        """Write the picture to ``path`` (``.png``, ``.svg`` or ``.pdf``), atomically."""
        return house.save(self.figure, path, dpi=self.figure.dpi)


def plot_frame(frame, ax=None, theme=None, style="auto", arrow_scale=1.0, parameters=None,
               size=6.0, dpi=100, azim=-60.0, elev=25.0, color="auto"):
    """Draw a :class:`~flocking.Frame`; returns the axes.

    ``parameters`` (a :class:`~flocking.Model` or a run's parameters) fill the title.
    With ``ax=None`` a whole figure (title, key, time label) is made through pyplot, so
    it shows in a notebook, in ``theme`` (default dark). With ``ax`` only the particles,
    walls and obstacles are drawn, on those axes and nowhere else (and, coloured by
    species, a legend naming them); ``theme`` defaults to the one that suits the axes'
    background. ``color``: ``heading``, ``species`` or ``auto`` (species if the frame
    has several).
    """
    check_color(color)
    if ax is None:
        scene = Scene.for_frame(frame, as_parameters(parameters), theme=theme or "dark", style=style,
                                size=size, dpi=dpi, arrow_scale=arrow_scale, azim=azim, elev=elev,
                                pyplot=True, color=color)
        scene.draw(frame)
        return scene.ax
    as_parameters(parameters)  # refused like the rest, even though only the title uses it
    theme = theme_of_color(ax.get_facecolor()) if theme is None else get_theme(theme)
    artist = FrameArtist(ax, frame, theme=theme, style=style, arrow_scale=arrow_scale, azim=azim, elev=elev,
                         color=color)
    handles = artist.legend_handles()
    if handles:
        house.legend(ax, theme, handles=handles, loc="upper right")
    return ax
