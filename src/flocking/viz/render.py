"""Frames as pictures: one matplotlib figure built once, whose artists each frame updates.

A :class:`Scene` lays out the box, a title with the run's parameters, a time label, the
colour-wheel key and (density maps) a colour bar, in the house style of
:mod:`.style`, on an Agg canvas (no display needed). Its layout is settled once, so
``scene.draw(frame)`` only updates artists and ``scene.rgb()`` returns the pixels: a
movie costs one redraw a frame, never a new figure. Three styles:

* ``arrows`` (2D): one arrow per particle coloured by heading (matplotlib quiver);
* ``density`` (2D): brightness = density with a colour bar, hue = local mean heading
  where there is local order (:mod:`.density`);
* ``perspective`` (3D): shaded cones along the headings through a perspective camera
  (:mod:`.perspective`), with an axis triad.

``auto`` picks arrows while each arrow gets :data:`ARROW_MIN_POINTS` on the page
(about 3e4 particles at the default size), density beyond, and perspective in 3D.

Particles are coloured by heading, or (``color="species"``, the default for a run with
several species) by species, with a legend naming them, or (``color="deviation"``, the
default in 3D) by the angle between each heading and the flock's mean heading, which
shows the structure of an ordered flock that a colour per heading paints in one hue.
Walls are a solid line along each wall axis' sides (periodic sides keep the plain
frame), obstacles solid discs (3D: shaded spheres) drawn over the particles, in every
style and both themes.

Pictures show box coordinates, each axis from 0 to L in units of the interaction
radius R, as the engine and the config files use them (a frame's points are centred,
as GSD files store them: :func:`box_coordinates` converts). The step and the polar
order are read out under the key, beside the box, not over the particles.

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

from ..model import Model, ParameterError
from . import style as house
from .colors import DEVIATION_FULL, deviation_colors, get_theme, heading_colors, theme_of_color, wheel_image
from .extensions import check_color, choose_color, obstacle_images, species_colors
from .density import GAMMA, DensityField, density_colormap, density_image, density_scale, density_ticks, grid_shape
from .local import local_headings
from .perspective import Camera, glyph_length, perspective_image

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


def as_parameters(parameters) -> dict | None:
    """A run's parameters (``{"model": {...}, ...}``) from a :class:`~flocking.Model`, the
    parameters a trajectory stored, or a model's ``to_dict()``; ``None`` stays ``None``."""
    if parameters is None:
        return None
    if isinstance(parameters, Model):
        return {"model": parameters.to_dict()}
    if isinstance(parameters, dict):
        return parameters if "model" in parameters else {"model": dict(parameters)}
    raise ParameterError(f"parameters: must be a Model or a dict of parameters (got {type(parameters).__name__})")


def positive(name: str, value) -> float:
    """``value`` as a finite float > 0, or a :class:`ParameterError` naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (np.isfinite(number) and number > 0):
        raise ParameterError(f"{name}: must be a number > 0 (got {value!r})")
    return number


def _g(value) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def box_coordinates(points, box_lengths) -> np.ndarray:
    """Centred points (a frame's, ``[-L/2, L/2)`` per axis, as GSD files hold them) in box
    coordinates, ``[0, L)``: the engine's and the config files'.

    >>> box_coordinates([[-16.0, 0.0], [15.5, -16.0]], (32.0, 32.0)).tolist()
    [[0.0, 16.0], [31.5, 0.0]]
    """
    box = np.asarray(box_lengths, dtype=float)
    return np.asarray(points, dtype=float)[..., : len(box)] + box / 2


def describe(parameters, dim: int, n: int, box_lengths) -> tuple[str, str]:
    """Title and caption (mathtext): what was simulated, and the parameters that matter,
    joined by ``" \u00b7 "`` so :func:`.style.title` can wrap them. The caption starts
    with the density and the noise (its kind and amplitude), the two control parameters.

    >>> describe(Model(n=2048, box=32.0, noise=1.0), 2, 2048, (32.0, 32.0))[1].split(" \u00b7 ")[:3]
    ['$\\\\rho$ = 2', 'angular noise $\\\\eta$ = 1', '$v_0$ = 0.5']
    """
    sides = [float(x) for x in box_lengths]
    box = f"$L$ = {sides[0]:.4g}" if len(set(sides)) == 1 else "box " + " \u00d7 ".join(f"{x:.4g}" for x in sides)
    first = f"Vicsek model \u00b7 {dim}D \u00b7 $N$ = {n:,} \u00b7 {box}"
    parameters = as_parameters(parameters)
    if not parameters:
        return first, ""
    m = parameters["model"]
    density = fr"$\rho$ = {n / float(np.prod(sides[:dim])):.3g}"
    noise = f"{m.get('noise_type', 'angular')} noise " + fr"$\eta$ = {_g(m['noise'])}"
    near = (f"$k$ = {m['k']} nearest" if m.get("neighbours") == "topological" else f"$R$ = {_g(m['radius'])}")
    parts = [density, noise, f"$v_0$ = {_g(m['speed'])}", near]
    if m.get("speeds") == "uniform":
        parts.append("speeds uniform")
    if m.get("alignment", 1.0) != 1.0:
        parts.append(fr"$\varepsilon$ = {_g(m['alignment'])}")
    if m.get("delay", 0):
        parts.append(fr"delay $\tau$ = {m['delay']}")
    if m.get("dt", 1.0) != 1.0:
        parts.append(fr"$\Delta t$ = {_g(m['dt'])}")
    if m.get("update", "backward") != "backward":
        parts.append(f"{m['update']} update")
    parts += _extension_parts(m, dim)
    parts.append(f"seed {m.get('seed', 0)}")
    return first, " \u00b7 ".join(parts)


def _extension_parts(m: dict, dim: int) -> list[str]:
    """Caption parts of the extensions a model's dict has on (docs/model.md's symbols)."""
    parts = []
    boundary = str(m.get("boundary", "periodic")).split(",")
    boundary = boundary * dim if len(boundary) == 1 else boundary
    walled = [axis for axis, kind in zip("xyz", boundary) if kind == "wall"]
    if walled:
        parts.append("walls" if len(walled) == dim else "walls on " + " and ".join(f"${a}$" for a in walled))
    if m.get("obstacles"):
        count = len(m["obstacles"])
        parts.append(f"{count} obstacle{'s' * (count > 1)}")
    if len(m.get("species") or ()) > 1:
        symbols = {"speed": "$v_0$", "noise": r"$\eta$", "alignment": r"$\varepsilon$", "chirality": r"$\omega$",
                   "field_strength": "$h$"}

        def one(sp):
            own = [f"{symbol} = {_g(sp[key])}" for key, symbol in symbols.items() if sp.get(key) is not None]
            return str(sp.get("name", "?")) + (f" ({', '.join(own)})" if own else "")

        parts.append("species " + ", ".join(one(sp) for sp in m["species"]))
    if m.get("coupling") is not None:
        parts.append("coupled species")
    if m.get("vision") is not None and m["vision"] < np.pi:
        parts.append(fr"vision $\theta_v$ = {_g(m['vision'])}")
    if m.get("alignment_rule", "polar") != "polar":
        parts.append(f"{m['alignment_rule']} alignment")
    if m.get("chirality"):
        parts.append(fr"$\omega$ = {_g(m['chirality'])}")
    if m.get("field_strength"):
        parts.append(f"field $h$ = {_g(m['field_strength'])}")
    return parts


#: The readout names each species' polar order for up to this many species.
READOUT_SPECIES = 4


def readout_lines(types, dt: float = 1.0, nematic: bool = False) -> int:
    """How many lines :func:`time_text` writes for these species, ``dt`` and alignment."""
    return 2 + (dt != 1.0) + bool(nematic) + (len(types) if 1 < len(types) <= READOUT_SPECIES else 0)


def time_text(frame, dt: float = 1.0, nematic: bool = False) -> str:
    """The readout under a picture's key, a line each: the step (and the time if
    ``dt != 1``), the nematic order ``S`` (for a run with nematic alignment, whose
    polar order tells little), each species' polar order (with several, up to
    :data:`READOUT_SPECIES`: species that move apart can each be ordered when the whole
    flock is not) and the polar order."""
    from ..analysis.order import mathtext_text, nematic_order

    lines = [f"step {frame.step:,}"]
    if dt != 1.0:
        lines.append(f"$t$ = {frame.step * dt:,.6g}")
    if nematic:
        lines.append(f"$S$ = {nematic_order(frame.headings):.3f}")
    if 1 < len(frame.types) <= READOUT_SPECIES:
        headings = frame.headings
        for s, name in enumerate(frame.types):
            mine = headings[frame.typeid == s]
            phi = float(np.linalg.norm(mine.sum(axis=0)) / len(mine)) if len(mine) else float("nan")
            lines.append(fr"$\varphi_{{\mathrm{{{mathtext_text(name)}}}}}$ = {phi:.3f}")
    return "\n".join([*lines, fr"$\varphi$ = {frame.polar_order:.3f}"])


def frame_density(frame, pixels: int) -> DensityField:
    """The :class:`DensityField` of a 2D frame, its longer side ``pixels`` bins, with its
    walls, obstacles and species."""
    box = frame.box_lengths
    return DensityField(frame.positions, frame.headings, box, grid_shape(box, pixels), walls=frame.walls,
                        obstacles=obstacle_images(frame.obstacles, box, frame.walls), typeid=frame.typeid,
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
        self.obstacles = obstacle_images(frame.obstacles, self.box, self.walls)
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
        self.rulers = self._make_rulers() if self.style == "perspective" and rulers else None
        self.zoom = ruler_zoom(points, house.fontsize(ax.figure)) if self.rulers else 1.0
        self.boundaries = self._boundaries() if self.dim == 2 else []
        self.update(frame)

    def colors(self, frame) -> np.ndarray:
        """``(N, 3)`` RGB of the particles: their headings', their species' or their
        deviations' from the mean heading colours."""
        if self.color == "species":
            return species_colors(len(self.types), self.theme)[frame.typeid]
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
                for name, c in zip(self.types, species_colors(len(self.types), self.theme))]

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
        species = species_colors(len(self.types), self.theme) if self.color == "species" else None
        self._show(density_image(field, self.theme, self.density_max, species), "bilinear")

    def _perspective(self, frame) -> None:
        rgb = perspective_image(frame.points, frame.headings, self.box, self.pixels, self.theme,
                                azim=self.azim, elev=self.elev,
                                length=glyph_length(frame.n, self.box, self.arrow_scale),
                                colors=self.colors(frame), walls=self.walls, obstacles=self.obstacles,
                                zoom=self.zoom)
        self._show(rgb, "antialiased")
        if self.rulers is not None:
            self._update_rulers()

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

    # -- the scale of 3D views: three edges of the box, ticked in box coordinates --------

    def _make_rulers(self) -> list:
        """Per axis: its tick marks (one line), tick labels and name, placed by :meth:`_update_rulers`."""
        t, fs = self.theme, house.fontsize(self.ax.figure)
        rulers = []
        for axis, name in enumerate("xyz"):
            ticks = nice_ticks(self.box[axis])[1:]  # no 0: two rulers start at most corners
            (marks,) = self.ax.plot([], [], color=t.text, lw=0.8, zorder=6, solid_capstyle="butt")
            labels = [self.ax.text(0, 0, f"{v:g}", color=t.text, fontsize=0.75 * fs, ha="center", va="center",
                                   zorder=6) for v in ticks]
            title = self.ax.text(0, 0, house.LABELS[name], color=t.text, fontsize=0.8 * fs, ha="center",
                                 va="center", zorder=6, rotation_mode="anchor")
            rulers.append((axis, ticks, marks, labels, title))
        return rulers

    def _update_rulers(self) -> None:
        """Put each axis' ruler on the edge along it that the camera sees on the box's
        outline: x and y on the bottom face's edges nearest the camera (the top face's
        seen from below), z on the vertical edge furthest left; labels offset outward
        from the box's centre on screen, each name along its edge."""
        cam = Camera(self.box, self.pixels, self.azim, self.elev, self.zoom)
        half = self.box / 2
        toward = -cam.forward  # from the box's centre toward the camera
        (u0,), (v0,), _ = cam.project(np.zeros((1, 3)))
        pixels = self.pixels / max(self.ax.get_window_extent().width, 1) * self.ax.figure.dpi / 72  # a point
        fs = house.fontsize(self.ax.figure)
        tick, gap = 0.35 * fs * pixels, 0.9 * fs * pixels
        for axis, ticks, marks, labels, title in self.rulers:
            corner = np.zeros(3)
            if axis < 2:
                other = 1 - axis
                corner[other] = np.copysign(half[other], toward[other])
                corner[2] = -np.copysign(half[2], toward[2])
            else:
                corner = min((np.array([sx * half[0], sy * half[1], 0.0]) for sx in (-1, 1) for sy in (-1, 1)),
                             key=lambda c: cam.project(c[None])[0][0])
            along = np.eye(3)[axis]
            start = corner - (corner[axis] + half[axis]) * along  # the end at coordinate 0
            u, v, _ = cam.project(start + np.outer([0.0, *ticks, half[axis]], along))
            u, v = u - 0.5, v - 0.5  # pixel centres are at +0.5; imshow puts pixel k at k
            (mu, mv), ends = (u[-1], v[-1]), (u[:-1], v[:-1])
            out = np.array([mu - (u0 - 0.5), mv - (v0 - 0.5)])
            out /= max(np.linalg.norm(out), 1e-9)
            xs, ys = [], []
            for k in range(len(ticks)):
                x, y = ends[0][k + 1], ends[1][k + 1]
                xs += [x, x + tick * out[0], np.nan]
                ys += [y, y + tick * out[1], np.nan]
                labels[k].set_position((x + (tick + gap) * out[0], y + (tick + gap) * out[1]))
            marks.set_data(xs, ys)
            angle = np.degrees(np.arctan2(-(ends[1][-1] - ends[1][0]), ends[0][-1] - ends[0][0]))
            angle = (angle + 90.0) % 180.0 - 90.0  # upright
            title.set_rotation(angle)
            title.set_position((mu + (tick + 2.5 * gap) * out[0], mv + (tick + 2.5 * gap) * out[1]))


def ruler_zoom(points: float, fontsize: float) -> float:
    """The camera's zoom of a 3D view ``points`` wide (1/72 inch) whose rulers' labels,
    in ``fontsize``, reach about 3.2 font sizes beyond the box's outline: the box (about
    0.94 of the view across at zoom 1, from most directions) shrinks to leave them room.

    >>> round(ruler_zoom(300.0, 8.7), 2), round(ruler_zoom(160.0, 8.0), 2)
    (0.87, 0.72)
    """
    return float(np.clip((0.5 - 3.2 * fontsize / points) / 0.47, 0.5, 0.95))


def nice_ticks(length: float) -> list[float]:
    """Ticks for an axis from 0 to ``length``: both ends and, between them, multiples
    of a round step (1, 2 or 5 times a power of ten) that leave room beside the ends.

    >>> nice_ticks(32.0), nice_ticks(100.0), nice_ticks(4.0)
    ([0.0, 10.0, 20.0, 32.0], [0.0, 50.0, 100.0], [0.0, 1.0, 2.0, 3.0, 4.0])
    """
    raw = length / 4
    power = 10.0 ** np.floor(np.log10(raw))
    step = min(m * power for m in (1, 2, 5, 10) if m * power >= raw * 0.999)
    inside = [float(k * step) for k in range(1, int(length // step) + 1) if 0.2 * length <= k * step <= 0.8 * length]
    return [0.0, *inside, float(length)]


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
        from matplotlib import colors as mcolors
        from matplotlib.cm import ScalarMappable

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
        self.figure = fig = house.new_figure(width_px / dpi, height or width, t, fs, dpi, pyplot)
        lines = 2.2  # the x label and its ticks, in lines of the base font
        if title:
            main, details = describe(parameters, dim, n, self.box)
            house.title(fig, main, details)
            lines += 1.1 * (fig._suptitle.get_text().count("\n") + 1)
            if details:
                lines += 0.88 * (fig._supxlabel.get_text().count("\n") + 1)
        bands = lines * fs / 72 * 1.35 + 0.15  # inches: title, caption, x label
        if auto_height:  # at most: the box takes about 70 % of the width
            height = 0.7 * width * aspect + bands
        height_px = 16 * max(4, round(height * dpi / 16))
        self.pixels = (width_px, height_px)
        fig.set_size_inches(width_px / dpi, height_px / dpi)
        points = 72 * min(0.7 * width, (height - bands) / aspect) * max(1.0, aspect)  # the box's longer side
        self.style = choose_style(style, dim, n, self.box, points)
        density = self.style == "density"
        key_width = max(0.16 * width, 9.0 * fs / 72)  # inches: the wheel and its labels at any size
        grid = fig.add_gridspec(1, 2, width_ratios=[width - key_width, key_width])
        self.ax = fig.add_subplot(grid[0, 0])
        if density:  # the key with the readout above, the density's colour bar below
            side = grid[0, 1].subgridspec(2, 1, height_ratios=[1.8, 1.6])
            self.key_axes = fig.add_subplot(side[0])
        else:  # the key with the readout, in the middle of the box's height
            self.key_axes = fig.add_subplot(grid[0, 1])
        # a box narrower than its slot (a wide figure) sits next to its keys, not apart
        self.ax.set_anchor("E")
        self.key_axes.set_anchor("W")
        self._style_axes(fs)
        model = (as_parameters(parameters) or {}).get("model", {})
        self.dt = model.get("dt", 1.0)
        self.nematic = model.get("alignment_rule") == "nematic"
        lines = readout_lines(self.types, self.dt, self.nematic) if time_label else 0
        if self.color == "species":
            self._key_label, self.time_label = species_key(self.key_axes, self.types, t, fs, lines)
        elif self.color == "deviation":
            self._key_label, self.time_label = deviation_key(self.key_axes, dim, t, fs, lines)
        else:
            self._key_label, self.time_label = heading_key(self.key_axes, dim, t, fs, density, lines)
        self.colorbar = None
        if density:
            cax = side[1].subgridspec(1, 3, width_ratios=[1, 0.5, 1])[0, 1]
            cax = fig.add_subplot(cax)
            cax.set_anchor("W")
            self._density_norm = mcolors.PowerNorm(GAMMA, vmin=0.0, vmax=density_max or 1.0)
            mappable = ScalarMappable(norm=self._density_norm, cmap=density_colormap(t))
            self.colorbar = fig.colorbar(mappable, cax=cax)
            self.colorbar.set_label(house.LABELS["density"], color=t.text, fontsize=0.9 * fs)
            cax.tick_params(colors=t.text, labelsize=0.8 * fs)
            self.colorbar.outline.set_edgecolor(t.edge)
        # settle the layout once, with the box's axes at their final size; then freeze it
        if dim == 2:
            self.ax.set_xlim(0.0, self.box[0])
            self.ax.set_ylim(0.0, self.box[1])
        self.ax.set_aspect("equal")
        self._layout()
        # the height that fits the box's aspect: give back what it leaves empty, or add what
        # it lacks when a shorter figure's layout made it narrower than its slot; the layout
        # of a shorter figure can move the margins, so the height is bracketed and halved
        short, tall = 0, None
        for _ in range(10 if auto_height else 0):
            self.ax.apply_aspect()
            slot, shown = self.ax.get_position(original=True), self.ax.get_position()
            spare = (slot.height - shown.height) * height_px
            lacking = (slot.width - shown.width) * width_px * self.box[1] / self.box[0] if dim == 2 else 0.0
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
            fig.set_size_inches(width_px / dpi, height_px / dpi)
            self._layout()
        fig.set_layout_engine("none")
        self._centre()
        bbox = self.ax.get_window_extent()
        self._args = dict(theme=t, style=self.style, arrow_scale=arrow_scale, azim=azim, elev=elev,
                          pixels=int(round(max(bbox.width, bbox.height))), density_max=density_max,
                          color=self.color)
        self.artist = None

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



# -- keys: what the colours mean, beside the box, with the readout of the step under them --------

#: Points per data unit of a key's axes at the narrowest (a key at least 9 font sizes
#: wide, less the layout's padding, spans 4 units), in font sizes: text placed by it
#: never runs out of the axes.
_UNIT = 1.6


def _below(ax, theme, fs: float, label: str, top: float, readout: int):
    """The key's caption ``label`` from ``y = top`` down (data units, centred at 0), an
    empty text of ``readout`` lines for :func:`time_text` under it (``None`` if 0), and
    the axes' limits around both."""
    t = get_theme(theme)
    small = 0.75 * fs
    caption = ax.text(0.0, top, label, ha="center", va="top", color=t.text, fontsize=small, linespacing=1.2)
    y = top - (label.count("\n") + 1) * 1.2 * 0.75 / _UNIT - 0.3
    text = None
    if readout:
        text = ax.text(0.0, y, "", ha="center", va="top", color=t.text, fontsize=0.85 * fs, family="monospace",
                       linespacing=1.3)
        y -= readout * 1.3 * 0.85 / _UNIT
    ax.set_xlim(-2.0, 2.0)
    ax.set_ylim(min(y - 0.05, -2.3), 1.65)
    return caption, text


def heading_key(ax, dim: int, theme, fs: float, ink: bool = False, readout: int = 2):
    """The colour wheel of headings on ``ax`` (its axes turned off): a ring in 2D, a disc
    grey toward +-z in 3D, in the colours of particles or (``ink``) of density maps.
    Returns ``(label, readout)``: the key's caption and an empty text of ``readout`` lines
    under it for :func:`time_text` (``None`` if 0). Every label lies inside the axes'
    limits, so a layout never shrinks the wheel to make room."""
    t = get_theme(theme)
    ax.imshow(wheel_image(192, dim, t, ink), interpolation="antialiased", extent=(-1, 1, -1, 1))
    ax.set_axis_off()
    small = 0.75 * fs
    for angle, text, ha in ((0, "0\u00b0", "left"), (90, "90\u00b0", "center"), (180, "180\u00b0", "right"),
                            (270, "270\u00b0", "center")):
        a = np.radians(angle)
        ax.text(1.1 * np.cos(a), 1.1 * np.sin(a), text, ha=ha, va="center" if angle in (0, 180)
                else ("bottom" if angle == 90 else "top"), color=t.text, fontsize=small)
    label = "heading" if dim == 2 else "heading\n(grey: $\\pm z$)"
    if ink:
        label = "heading\n(grey: no order)"
    return _below(ax, t, fs, label, -1.62, readout)


def deviation_key(ax, dim: int, theme, fs: float, readout: int = 2):
    """The key of :func:`.colors.deviation_colors`: the disc of 3D headings, grey at its
    centre (along the mean heading) and full at its rim (:data:`.colors.DEVIATION_FULL`
    or more), its top the turn toward +z (2D: to the left); laid out as
    :func:`heading_key`, and returns ``(label, readout)`` as it does."""
    t = get_theme(theme)
    ax.imshow(wheel_image(192, 3, t), interpolation="antialiased", extent=(-1, 1, -1, 1))
    ax.set_axis_off()
    ax.text(0.0, 1.1, "+z" if dim == 3 else "left", ha="center", va="bottom", color=t.text, fontsize=0.75 * fs)
    full = f"{np.degrees(DEVIATION_FULL):.0f}\u00b0"
    return _below(ax, t, fs, f"heading relative\nto the flock's mean\n(grey: along it;\nrim: {full} or more)",
                  -1.2, readout)


def species_key(ax, types, theme, fs: float, readout: int = 2):
    """The species' names beside squares of their colours, top down, on ``ax`` (spaced
    in points, so the rows read alike at every size); returns ``(None, readout)``, the
    readout (``readout`` lines, none if 0) under the last name."""
    t = get_theme(theme)
    ax.set_axis_off()
    small = 0.75 * fs
    line = 1.6 * small
    anchor = dict(xy=(0.12, 0.98), xycoords="axes fraction", textcoords="offset points", va="top",
                  fontsize=small, annotation_clip=False)
    ax.annotate("species", xytext=(0, 0), color=t.text, **anchor)
    for s, (name, rgb) in enumerate(zip(types, species_colors(len(types), t))):
        y = -line * (s + 1.2)
        ax.annotate("\u25a0", xytext=(0, y), color=tuple(rgb), **anchor)
        ax.annotate(name, xytext=(1.4 * small, y), color=t.text, **anchor)
    if not readout:
        return None, None
    return None, ax.annotate("", xytext=(0, -line * (len(types) + 2.0)), color=t.text, linespacing=1.3,
                             family="monospace", **{**anchor, "fontsize": 0.85 * fs})

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
