"""Movies and pictures of coarse-grained fields (:mod:`flocking.fields`), in the house style.

Each frame shows the density of the bins (particles per unit area; 3D: summed along z,
per unit area of the x-y plane) as brightness on one scale for the whole movie, and the
bins' mean heading as hue with the local polar order ``|sum u| / count`` as chroma where
it is significant (``|sum u|^2`` at least :data:`flocking.viz.density.SIGNIFICANT` times
its mean ``count`` for random headings), as the density maps of particles do.
"""

from __future__ import annotations

import os

import numpy as np

from ..model import ParameterError
from . import style as house
from .colors import angle_colors, get_theme
from .density import GAMMA, SIGNIFICANT, density_colormap, density_ticks, nice_ceiling


def fields_path(source: str) -> str:
    """The fields file of a run folder, or ``source`` itself (a ``.nc`` file)."""
    path = os.path.join(source, "fields.nc") if os.path.isdir(source) else source
    if not os.path.isfile(path):
        raise ParameterError(f"RUN_DIR: no fields file at {path!r} (flocking run --fields BIN writes one)")
    return path


def planes(ds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(count, px, py)`` per frame as ``(time, y, x)``: 3D fields summed along z."""
    names = ("count", "polarisation_x", "polarisation_y")
    arrays = [np.asarray(ds[name].values, dtype=float) for name in names]
    if arrays[0].ndim == 4:
        arrays = [a.sum(axis=1) for a in arrays]
    return tuple(arrays)


def frame_image(count, px, py, area: float, vmax: float, theme) -> np.ndarray:
    """RGB ``(y, x, 3)`` of one frame, rows upward (``imshow(origin="lower")``)."""
    t = get_theme(theme)
    density = count / area
    alpha = np.clip(density / vmax, 0.0, 1.0) ** GAMMA
    s2 = px * px + py * py
    significance = np.divide(s2, count, out=np.zeros_like(s2), where=count > 0)
    trust = np.clip(2.0 * significance / SIGNIFICANT - 1.0, 0.0, 1.0)
    order = np.divide(np.sqrt(s2), count, out=np.zeros_like(s2), where=count > 0)
    ink = angle_colors(np.arctan2(py, px), t, order * trust, ink=True)
    background = np.asarray(t.background, float)
    return np.clip(background + alpha[..., None] * (ink - background), 0.0, 1.0)


class FieldScene:
    """One reused figure: the field image, a density colour bar, the step in the title."""

    def __init__(self, ds, theme="dark", dpi=120.0, width=6.4):
        self.theme = get_theme(theme)
        self.count, self.px, self.py = planes(ds)
        box = np.asarray(ds.attrs["box"], dtype=float)
        widths = np.asarray(ds.attrs["bin_widths"], dtype=float)
        self.area = float(widths[0] * widths[1])
        self.steps = np.asarray(ds["step"].values)
        density = self.count / self.area  # one scale, as the particles' density maps choose theirs
        self.vmax = nice_ceiling(max(float(np.percentile(density, 99.5)), 2.0 * float(density.mean())))
        self.dpi = float(dpi)
        # pixels a multiple of 16 (H.264's macro blocks)
        w_px = 16 * round(width * dpi / 16)
        h_px = 16 * round(w_px * 0.82 * box[1] / box[0] / 16)
        self.pixels = (int(w_px), int(h_px))
        self.fig = house.new_figure(w_px / dpi, h_px / dpi, self.theme, fontsize=9.0, dpi=dpi)
        ax = self.fig.subplots()
        house.style_axes(ax, self.theme)
        ax.grid(False)
        self.image = ax.imshow(self.rgb(0), origin="lower", extent=(0, box[0], 0, box[1]), interpolation="nearest")
        house.label_axes(ax, "x", "y")
        self.ax = ax
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import PowerNorm

        mappable = ScalarMappable(PowerNorm(GAMMA, 0.0, self.vmax), density_colormap(self.theme))
        bar = self.fig.colorbar(mappable, ax=ax, ticks=density_ticks(self.vmax), shrink=0.85)
        bar.set_label("density (particles per unit area)" + (", summed over z" if len(box) == 3 else ""),
                      color=self.theme.text)
        bar.ax.tick_params(colors=self.theme.text)

    def rgb(self, k: int) -> np.ndarray:
        return frame_image(self.count[k], self.px[k], self.py[k], self.area, self.vmax, self.theme)

    def draw(self, k: int) -> FieldScene:
        self.image.set_data(self.rgb(k))
        self.ax.set_title(f"coarse-grained fields, step {int(self.steps[k])}", color=self.theme.text)
        return self

    def pixels_rgb(self) -> np.ndarray:
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3]


def write_field_movie(source, output, *, theme="dark", fps=20.0, dpi=120.0, start=None, stop=None, stride=1,
                      progress=False) -> str:
    """A movie (``.mp4`` or ``.gif``) of the fields of ``source`` (a run folder or a
    fields file), frames ``start:stop:stride``. Returns the output path."""
    from ..fields import open as open_fields
    from .movie import FORMATS, encode_gif, encode_mp4, gif_palette, samples, select_frames

    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in FORMATS:
        raise ParameterError(f"output: must end in .mp4 or .gif (got {output!r})")
    ds = open_fields(fields_path(os.fspath(source)))
    scene = FieldScene(ds, theme=theme, dpi=dpi)
    indices = select_frames(len(scene.steps), start, stop, stride)
    frames = (scene.draw(k).pixels_rgb().copy() for k in indices)
    tmp = os.path.join(os.path.dirname(os.path.abspath(output)), f".{os.path.basename(output)}.part{ext}")
    try:
        if ext == ".mp4":
            encode_mp4(tmp, frames, scene.pixels, float(fps))
        else:
            palette = gif_palette([scene.draw(indices[k]).pixels_rgb().copy() for k in samples(indices, 3)])
            encode_gif(tmp, frames, float(fps), palette)
        os.replace(tmp, output)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return output


def write_field_picture(source, output, *, frame=-1, theme="dark", dpi=None) -> str:
    """One frame (index, negative from the end) of the fields of ``source`` as a picture."""
    from ..fields import open as open_fields

    house.check_format(output)
    ds = open_fields(fields_path(os.fspath(source)))
    scene = FieldScene(ds, theme=theme, dpi=house.check_dpi(dpi) or house.DPI)
    count = len(scene.steps)
    if not -count <= frame < count:
        raise ParameterError(f"frame: must be a frame index in [{-count}, {count - 1}] (got {frame!r})")
    return house.save(scene.draw(frame % count).fig, output, dpi=scene.dpi)
