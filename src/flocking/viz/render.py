"""Frames as pictures: one matplotlib figure built once, whose artists each frame updates.

A :class:`Scene` lays out the box, a title with the run's parameters, a time label and a
colour-wheel key, on an Agg canvas (no display needed). ``scene.draw(frame)`` updates
the artists and ``scene.rgb()`` returns the pixels, so a movie costs one redraw a frame,
never a new figure. Three styles:

* ``arrows`` (2D): one arrow per particle coloured by heading (matplotlib quiver);
* ``density`` (2D): hue = local mean heading, brightness = density (:mod:`.raster`);
* ``perspective`` (3D): depth-cued particles through a perspective camera.

``auto`` picks arrows while each arrow gets a few pixels, density beyond (about 3e4
particles at the default size), and perspective in 3D.

>>> import flocking
>>> frame = flocking.Frame(0, 2, [4, 4], np.zeros((1, 3)), np.array([[0.5, 0, 0]]))
>>> scene = Scene.for_frame(frame, size=2.0, dpi=64)
>>> scene.draw(frame).rgb().shape
(128, 128, 3)
"""

from __future__ import annotations

import numpy as np

from ..model import ParameterError
from .colors import get_theme, heading_colors, wheel_image
from .raster import density_bins, density_image, perspective_image

STYLES = ("auto", "arrows", "density", "perspective")

#: ``auto`` draws arrows while the mean spacing between particles is at least this many pixels.
ARROW_MIN_PIXELS = 3.5


def check_style(style: str, dim: int) -> str:
    if style not in STYLES:
        raise ParameterError(f"style: must be one of {', '.join(STYLES)} (got {style!r})")
    if dim == 3 and style in ("arrows", "density"):
        raise ParameterError(f"style: 3D frames are drawn in perspective (got {style!r})")
    if dim == 2 and style == "perspective":
        raise ParameterError("style: perspective is for 3D frames (got 'perspective')")
    return style


def choose_style(style: str, dim: int, n: int, box_lengths, pixels: int) -> str:
    """Resolve ``auto``: perspective in 3D, else arrows if they get room, else density."""
    style = check_style(style, dim)
    if style != "auto":
        return style
    if dim == 3:
        return "perspective"
    spacing = np.sqrt(np.prod(box_lengths[:2]) / max(n, 1)) * pixels / max(box_lengths[:2])
    return "arrows" if spacing >= ARROW_MIN_PIXELS else "density"


def _g(value) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def describe(parameters: dict | None, dim: int, n: int, box_lengths) -> tuple[str, str]:
    """Two title lines: what was simulated, and with which parameters."""
    sides = [float(x) for x in box_lengths]
    box = f"L = {_g(sides[0])}" if len(set(sides)) == 1 else "box " + " \u00d7 ".join(map(_g, sides))
    first = f"Vicsek model \u00b7 {dim}D \u00b7 N = {n:,} \u00b7 {box}"
    if not parameters or "model" not in parameters:
        return first, ""
    m = parameters["model"]
    noise = f"\u03b7 = {_g(m['noise'])}" + (" (vectorial)" if m.get("noise_type") == "vectorial" else "")
    near = (f"k = {m['k']} nearest" if m.get("neighbours") == "topological" else f"R = {_g(m['radius'])}")
    parts = [noise, f"v\u2080 = {_g(m['speed'])}", near]
    if m.get("speeds") == "uniform":
        parts.append("speeds uniform")
    if m.get("alignment", 1.0) != 1.0:
        parts.append(f"\u03b5 = {_g(m['alignment'])}")
    if m.get("delay", 0):
        parts.append(f"delay {m['delay']}")
    if m.get("dt", 1.0) != 1.0:
        parts.append(f"dt = {_g(m['dt'])}")
    if m.get("update", "backward") != "backward":
        parts.append(f"{m['update']} update")
    parts.append(f"seed {m.get('seed', 0)}")
    return first, " \u00b7 ".join(parts)


def time_text(frame, dt: float = 1.0) -> str:
    text = f"step {frame.step:,}"
    if dt != 1.0:
        text += f"  (t = {frame.step * dt:.4g})"
    return text + f"   \u03c6 = {frame.polar_order():.3f}"


class FrameArtist:
    """The particles of one frame on a matplotlib axes; :meth:`update` redraws them in place."""

    def __init__(self, ax, frame, theme="dark", style="auto", arrow_scale=1.0, pixels=None,
                 azim=-60.0, elev=25.0):
        self.ax = ax
        self.theme = get_theme(theme)
        self.dim = frame.dim
        self.box = np.asarray(frame.box_lengths, dtype=float)
        if pixels is None:
            bbox = ax.get_window_extent()
            pixels = int(max(bbox.width, bbox.height))
        self.pixels = max(int(pixels), 16)
        self.style = choose_style(style, frame.dim, frame.n, self.box, self.pixels)
        self.arrow_scale = float(arrow_scale)
        if not np.isfinite(self.arrow_scale) or self.arrow_scale <= 0:
            raise ParameterError(f"arrow_scale: must be a number > 0 (got {arrow_scale!r})")
        self.azim, self.elev = float(azim), float(elev)
        ax.set_facecolor(self.theme.background)
        if self.dim == 2:
            lx, ly = self.box[:2]
            ax.set_xlim(-lx / 2, lx / 2)
            ax.set_ylim(-ly / 2, ly / 2)
            ax.set_aspect("equal")
        self._artist = None
        self.update(frame)

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
        else:
            self._image(frame)

    def _arrows(self, frame) -> None:
        heads = frame.headings
        length = self.arrow_length
        colors = heading_colors(heads, self.theme)
        uv = heads * length
        if self._artist is None or len(self._artist.U) != frame.n:
            if self._artist is not None:
                self._artist.remove()
            self._artist = self.ax.quiver(
                frame.positions[:, 0], frame.positions[:, 1], uv[:, 0], uv[:, 1], color=colors,
                angles="xy", scale_units="xy", scale=1.0, units="xy", width=0.16 * length,
                headwidth=3.0, headlength=3.2, headaxislength=2.8, pivot="middle", minlength=0.0,
                linewidth=0)
        else:
            self._artist.set_offsets(frame.positions)
            self._artist.set_UVC(uv[:, 0], uv[:, 1])
            self._artist.set_facecolor(colors)

    def _image(self, frame) -> None:
        if self.style == "density":
            shape = density_bins(frame.n, self.box, self.pixels)
            rgb = density_image(frame.positions, frame.headings, self.box, shape, self.theme)
            lx, ly = self.box[:2]
            extent = (-lx / 2, lx / 2, -ly / 2, ly / 2)
        else:
            rgb = perspective_image(frame.points, frame.headings, self.box, self.pixels, self.theme,
                                    azim=self.azim, elev=self.elev)
            extent = None
        rgb = np.clip(rgb, 0.0, 1.0)
        if self._artist is None or self._artist.get_array().shape != rgb.shape:
            if self._artist is not None:
                self._artist.remove()
            self._artist = self.ax.imshow(rgb, extent=extent, interpolation="bilinear"
                                          if self.style == "density" else "antialiased")
        else:
            self._artist.set_data(rgb)


class Scene:
    """A whole picture: box, title, time label and colour key, on its own Agg canvas.

    ``size`` is the figure width in inches and ``dpi`` its pixels per inch; the pixel
    size is rounded to a multiple of 16 so that H.264 takes it as it is.
    """

    def __init__(self, dim, n, box_lengths, parameters=None, theme="dark", style="auto", size=6.0,
                 dpi=120, arrow_scale=1.0, time_label=True, azim=-60.0, elev=25.0, pyplot=False):
        from matplotlib.figure import Figure

        self.theme = get_theme(theme)
        check_style(style, dim)
        size, dpi = float(size), float(dpi)
        if not np.isfinite(size) or not 0.5 <= size <= 100:
            raise ParameterError(f"size: must be in [0.5, 100] inches (got {size!r})")
        if not np.isfinite(dpi) or not 10 <= dpi <= 1000:
            raise ParameterError(f"dpi: must be in [10, 1000] (got {dpi!r})")
        self.dim = dim
        self.box = np.asarray(box_lengths, dtype=float)[:dim]
        aspect = self.box[1] / self.box[0] if dim == 2 else 1.0
        aspect = float(np.clip(aspect, 0.25, 4.0))
        # the box takes 72 % of the width, the key column the right; title band and margins
        # add 24 % of the width to the height
        width_px = 16 * max(4, round(size * dpi / 16))
        box_w = 0.72 * width_px
        height_px = 16 * max(4, round((box_w * aspect + 0.24 * width_px) / 16))
        self.pixels = (width_px, height_px)
        figsize = (width_px / dpi, height_px / dpi)
        if pyplot:
            import matplotlib.pyplot as plt

            self.figure = plt.figure(figsize=figsize, dpi=dpi)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg

            self.figure = Figure(figsize=figsize, dpi=dpi)
            FigureCanvasAgg(self.figure)
        fig, t = self.figure, self.theme
        fig.set_facecolor(t.figure)
        fs = max(5.0, 9.5 * width_px / dpi / 6.0)  # font size follows the figure's width
        W, H = width_px, height_px
        box_h = min(box_w * aspect, H - 0.24 * W)
        box_w = box_h / aspect
        left, bottom = 0.085 * W, 0.07 * W
        self.ax = fig.add_axes([left / W, bottom / H, box_w / W, box_h / H])
        self._style_axes(fs)
        title, subtitle = describe(parameters, dim, n, self.box)
        top = (bottom + box_h) / H
        fig.text(left / W, top + 0.095 * W / H, title, color=t.text, fontsize=1.25 * fs,
                 fontweight="bold", va="bottom", ha="left")
        fig.text(left / W, top + 0.035 * W / H, subtitle, color=t.text, fontsize=fs, va="bottom",
                 ha="left", alpha=0.85)
        self._key(dim, fs, (left + box_w) / W, top)
        self.time_label = None
        if time_label:
            self.time_label = self.ax.text(
                0.015, 0.985, "", transform=self.ax.transAxes, ha="left", va="top", color=t.text,
                fontsize=fs, family="monospace", zorder=5,
                bbox=dict(boxstyle="round,pad=0.3", fc=t.figure, ec="none", alpha=0.65))
        self.dt = (parameters or {}).get("model", {}).get("dt", 1.0)
        self._args = dict(theme=self.theme, style=style, arrow_scale=arrow_scale, azim=azim, elev=elev,
                          pixels=int(max(box_w, box_h)))
        self.artist = None

    @classmethod
    def for_frame(cls, frame, parameters=None, **options) -> Scene:
        return cls(frame.dim, frame.n, frame.box_lengths, parameters, **options)

    @classmethod
    def for_trajectory(cls, traj, **options) -> Scene:
        return cls.for_frame(traj[0], traj.parameters, **options)

    def _style_axes(self, fs: float) -> None:
        ax, t = self.ax, self.theme
        if self.dim == 3:
            ax.set_axis_off()
            return
        ax.set_xlabel("x", color=t.text, fontsize=fs)
        ax.set_ylabel("y", color=t.text, fontsize=fs, rotation=0, labelpad=fs * 0.8)
        ax.tick_params(colors=t.text, labelsize=0.85 * fs, length=3)
        for spine in ax.spines.values():
            spine.set_color(t.edge)

    def _key(self, dim: int, fs: float, x0: float, top: float) -> None:
        W, H = self.pixels
        side = 0.105 * W
        column = 1.0 - x0  # figure fraction right of the box
        ax = self.figure.add_axes([x0 + (column - side / W) / 2, top - side / H - 0.03 * W / H,
                                   side / W, side / H])
        ax.imshow(wheel_image(128, dim, self.theme), interpolation="antialiased")
        ax.set_axis_off()
        t = self.theme
        label = "heading" if dim == 2 else "heading\n(pale: \u00b1z)"
        ax.text(0.5, -0.2, label, transform=ax.transAxes, ha="center", va="top", color=t.text,
                fontsize=0.85 * fs)
        for angle, text in ((0, "0\u00b0"), (90, "90\u00b0"), (180, "180\u00b0"), (270, "270\u00b0")):
            a = np.radians(angle)
            ax.text(0.5 + 0.64 * np.cos(a), 0.5 + 0.64 * np.sin(a), text, transform=ax.transAxes,
                    ha="center", va="center", color=t.text, fontsize=0.62 * fs, alpha=0.8)
        self.key_axes = ax

    def draw(self, frame, azim: float | None = None) -> Scene:
        if self.artist is None:
            self.artist = FrameArtist(self.ax, frame, **self._args)
            if self.artist.style == "density":
                self.key_axes.texts[0].set_text("hue: heading\nstrength: density")
        else:
            self.artist.update(frame, azim=azim)
        if self.time_label is not None:
            self.time_label.set_text(time_text(frame, self.dt))
        return self

    def rgb(self) -> np.ndarray:
        """The picture as an ``(H, W, 3)`` uint8 array."""
        self.figure.canvas.draw()
        return np.asarray(self.figure.canvas.buffer_rgba())[..., :3].copy()

    def save(self, path: str) -> None:
        self.figure.savefig(path, dpi=self.figure.dpi, facecolor=self.figure.get_facecolor())


def plot_frame(frame, ax=None, theme="dark", style="auto", arrow_scale=1.0, parameters=None,
               size=6.0, dpi=100, azim=-60.0, elev=25.0):
    """Draw a :class:`~flocking.Frame`; returns the axes.

    With ``ax=None`` a whole figure (title, key, time label) is made with pyplot, so it
    shows in a notebook; with ``ax`` only the particles are drawn on it.
    """
    if ax is None:
        scene = Scene.for_frame(frame, parameters, theme=theme, style=style, size=size, dpi=dpi,
                                arrow_scale=arrow_scale, azim=azim, elev=elev, pyplot=True)
        scene.draw(frame)
        return scene.ax
    FrameArtist(ax, frame, theme=theme, style=style, arrow_scale=arrow_scale, azim=azim, elev=elev)
    return ax


def polar_order_figure(steps, phi, parameters=None, dim=2, n=0, box_lengths=(1, 1), theme="dark",
                       size=7.0, dpi=120):
    """The polar order against the step, on its own Agg figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = get_theme(theme)
    fig = Figure(figsize=(size, size * 0.55), dpi=dpi)
    FigureCanvasAgg(fig)
    fig.set_facecolor(t.figure)
    ax = fig.add_axes([0.1, 0.14, 0.86, 0.66])
    ax.set_facecolor(t.background)
    steps, phi = np.asarray(steps), np.asarray(phi)
    ax.plot(steps, phi, color="#4cc9f0" if t.name == "dark" else "#1f5fa8", lw=1.2)
    if len(phi) >= 4:
        tail = phi[len(phi) // 2:]
        ax.axhline(tail.mean(), color="#f4a261", lw=1, ls="--",
                   label=f"mean of second half {tail.mean():.3f} \u00b1 {tail.std():.3f}")
        ax.legend(loc="lower right", frameon=False, labelcolor=t.text, fontsize=9)
    ax.set_ylim(0, 1.02)
    if len(steps) > 1:
        ax.set_xlim(steps[0], steps[-1])
    ax.set_xlabel("step", color=t.text)
    ax.set_ylabel("polar order \u03c6", color=t.text)
    ax.tick_params(colors=t.text)
    ax.grid(color=t.edge, alpha=0.3, lw=0.5)
    for spine in ax.spines.values():
        spine.set_color(t.edge)
    title, subtitle = describe(parameters, dim, n, box_lengths)
    fig.text(0.1, 0.93, title, color=t.text, fontsize=11.5, fontweight="bold", va="bottom")
    fig.text(0.1, 0.86, subtitle, color=t.text, fontsize=9.5, va="bottom", alpha=0.85)
    return fig
