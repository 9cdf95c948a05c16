"""Movies, single-frame pictures, and the pictures a run leaves behind.

:func:`write_movie` streams frames from a trajectory through one reused :class:`Scene`
into H.264 (``.mp4``, the ffmpeg that ``imageio-ffmpeg`` ships) or a ``.gif`` (Pillow,
one palette for the whole movie, dithered): one frame in memory at a time for mp4.
A density map keeps one density scale for the whole movie, read from a few frames
spread over it. :func:`write_picture` draws one frame as ``.png``, ``.svg`` or ``.pdf``.
Files are written under a temporary name and renamed at the end, so a failed or
interrupted one leaves nothing half-written. :func:`after_run` is what ``flocking run``
calls when it is done.
"""

from __future__ import annotations

import csv
import os

import numpy as np

from ..model import ParameterError
from . import style as house
from .colors import check_color, get_theme
from .particles import check_style
from .scene import Scene

FORMATS = (".mp4", ".gif")
#: Quality of movies (x264's constant rate factor: lower is better and larger).
CRF = 18


def open_run(trajectory):
    """``(trajectory, owned)``: an open :class:`flocking.Trajectory` as it is (not owned),
    or the one of a path to a GSD file or a run folder, opened here (owned: the caller
    closes it)."""
    from ..trajectory import Trajectory

    if isinstance(trajectory, Trajectory):
        return trajectory, False
    path = os.fspath(trajectory)
    if os.path.isdir(path):
        path = os.path.join(path, "trajectory.gsd")
    if not os.path.isfile(path):
        raise ParameterError(f"no trajectory file at {path!r}")
    from ..trajectory import open as open_trajectory

    return open_trajectory(path), True


def select_frames(length: int, start=None, stop=None, stride=1) -> range:
    """The frame indices ``start:stop:stride`` of ``length`` frames, refused if empty."""
    if stride is None or int(stride) < 1:
        raise ParameterError(f"stride: must be a whole number >= 1 (got {stride!r})")
    indices = range(*slice(start, stop, int(stride)).indices(length))
    if len(indices) == 0:
        raise ParameterError(f"start: frames {start}:{stop}:{stride} select none of the {length} frames")
    return indices


def check_rotate(rotate: bool, dim: int) -> None:
    if rotate and dim != 3:
        raise ParameterError(f"rotate: turns the camera around a 3D box; this trajectory is {dim}D")


def samples(indices, count: int = 5) -> list[int]:
    """Up to ``count`` positions in ``indices``, evenly spread, first and last included."""
    return sorted({int(round(x)) for x in np.linspace(0, len(indices) - 1, min(count, len(indices)))})


def fix_density_scale(scene: Scene, traj, indices) -> None:
    """Give a density movie one scale: the largest that a few of its frames ask for."""
    if scene.style != "density" or scene.density_max is not None:
        return
    from .density import density_scale

    scene.set_density_max(density_scale([scene.density_field(traj[indices[k]]) for k in samples(indices)]))


def write_movie(trajectory, output, *, theme="dark", style="auto", fps=20.0, dpi=120, size=6.0,
                start=None, stop=None, stride=1, arrow_scale=1.0, time_label=True, rotate=False,
                azim=-60.0, elev=25.0, progress=False, crf=CRF, color="auto") -> str:
    """Write ``trajectory`` (a path, run folder or :class:`Trajectory`) to ``output``.

    ``output`` ends in ``.mp4`` (H.264) or ``.gif``. ``rotate`` turns a 3D camera once
    around the box over the movie (a 2D trajectory is refused). ``color``: ``heading``,
    ``species`` or ``auto`` (species if the run has several). Returns the output path.
    """
    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in FORMATS:
        raise ParameterError(f"output: must end in .mp4 or .gif (got {output!r})")
    fps = float(fps)
    if not np.isfinite(fps) or not 0 < fps <= 240:
        raise ParameterError(f"fps: must be in (0, 240] (got {fps!r})")
    get_theme(theme)
    check_color(color)
    traj, owned = open_run(trajectory)
    try:
        indices = select_frames(len(traj), start, stop, stride)
        first = traj[indices[0]]
        check_style(style, first.dim)
        check_rotate(rotate, first.dim)
        scene = Scene.for_frame(first, traj.parameters, theme=theme, style=style, size=size, dpi=dpi,
                                arrow_scale=arrow_scale, time_label=time_label, azim=azim, elev=elev, color=color)
        fix_density_scale(scene, traj, indices)
        turn = 360.0 / len(indices) if rotate else 0.0

        def render(k):
            frame = first if k == 0 else traj[indices[k]]
            return scene.draw(frame, azim=azim + k * turn if rotate else None).rgb()

        from tqdm.auto import tqdm

        stream = tqdm((render(k) for k in range(len(indices))), total=len(indices), unit="frame",
                      disable=not progress, desc=os.path.basename(output), dynamic_ncols=True, leave=False)
        folder = os.path.dirname(os.path.abspath(output))
        tmp = os.path.join(folder, f".{os.path.basename(output)}.part{ext}")
        try:
            if ext == ".mp4":
                encode_mp4(tmp, stream, scene.pixels, fps, crf)
            else:
                palette = gif_palette([render(k) for k in samples(indices, 3)])
                encode_gif(tmp, stream, fps, palette)
            os.replace(tmp, output)
        finally:
            stream.close()
            if os.path.exists(tmp):
                os.remove(tmp)
    finally:
        if owned:
            traj.close()
    return output


def encode_mp4(path, frames, pixels, fps, crf=CRF) -> None:
    """H.264 (yuv420p) of RGB ``frames`` of ``pixels = (width, height)``, a multiple of 16."""
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(path, pixels, fps=fps, codec="libx264", quality=None,
                                         pix_fmt_out="yuv420p", macro_block_size=16,
                                         output_params=["-crf", str(int(crf)), "-preset", "fast",
                                                        "-movflags", "+faststart"])
    writer.send(None)
    try:
        for rgb in frames:
            writer.send(np.ascontiguousarray(rgb))
    finally:
        writer.close()


def gif_palette(images, exact: int = 16):
    """One 256-colour palette for a whole movie, from a few of its frames: their ``exact``
    most frequent colours (backgrounds, text) as they are, the rest by maximum coverage,
    which keeps the colours of small regions such as the colour wheel."""
    from PIL import Image

    stacked = np.concatenate(list(images), axis=0)
    colours, counts = np.unique(stacked.reshape(-1, 3), axis=0, return_counts=True)
    frequent = colours[np.argsort(-counts, kind="stable")[:exact]]
    rest = Image.fromarray(stacked).quantize(colors=256 - len(frequent), method=Image.Quantize.MAXCOVERAGE,
                                             dither=Image.Dither.NONE)
    entries = np.vstack([frequent, np.reshape(rest.getpalette()[:3 * (256 - len(frequent))], (-1, 3))])
    palette = Image.new("P", (1, 1))
    palette.putpalette(entries.astype(np.uint8).ravel().tolist())
    return palette


def encode_gif(path, frames, fps, palette) -> None:
    """A looping GIF of RGB ``frames``, each dithered (Floyd-Steinberg) onto ``palette``;
    every frame is kept as one byte a pixel until the file is written."""
    from PIL import Image

    images = [Image.fromarray(rgb).quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG)
              for rgb in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=1000.0 / fps, loop=0,
                   disposal=1, optimize=False)


def write_picture(trajectory, output, *, frame=-1, theme="dark", style="auto", dpi=None, size=6.0,
                  arrow_scale=1.0, time_label=True, azim=-60.0, elev=25.0, title=True, color="auto") -> str:
    """One frame of ``trajectory`` (index ``frame``, default the last) as a ``.png``,
    ``.svg`` or ``.pdf`` picture. Returns the output path."""
    output = os.fspath(output)
    house.check_format(output)
    dpi = house.check_dpi(dpi) or house.DPI
    get_theme(theme)
    check_color(color)
    traj, owned = open_run(trajectory)
    try:
        if isinstance(frame, bool) or not isinstance(frame, (int, np.integer)) \
                or not -len(traj) <= frame < len(traj):
            raise ParameterError(f"frame: must be a frame index in [{-len(traj)}, {len(traj) - 1}] (got {frame!r})")
        shown = traj[int(frame)]
        scene = Scene.for_frame(shown, traj.parameters, theme=theme, style=style, size=size, dpi=dpi,
                                arrow_scale=arrow_scale, time_label=time_label, azim=azim, elev=elev,
                                title=title, color=color)
        return scene.draw(shown).save(output)
    finally:
        if owned:
            traj.close()


def read_observables(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, polar_order)`` columns of an ``observables.csv``."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = [(int(r["step"]), float(r["polar_order"])) for r in csv.DictReader(f)]
    steps, phi = zip(*rows) if rows else ((), ())
    return np.asarray(steps), np.asarray(phi)


def check_picture_options(theme="dark", dpi=None, fmt="png", color="auto") -> None:
    """Refuse a bad theme, resolution, picture format or colouring before anything runs."""
    get_theme(theme)
    check_color(color)
    house.check_dpi(dpi)
    if fmt not in house.FORMATS:
        raise ParameterError(f"plot_format: must be one of {', '.join(house.FORMATS)} (got {fmt!r})")


def write_plots(run_dir: str, theme: str = "dark", dpi=None, fmt: str = "png", size=6.0,
                color: str = "auto") -> list[str]:
    """``snapshot.<fmt>`` (last frame) and ``polar_order.<fmt>`` in ``run_dir``; their paths."""
    from .timeseries import polar_order_figure

    check_picture_options(theme, dpi, fmt, color)
    traj, _ = open_run(run_dir)
    written = []
    with traj:
        last = traj[-1]
        params = traj.parameters
        written.append(write_picture(traj, os.path.join(run_dir, f"snapshot.{fmt}"), theme=theme, dpi=dpi,
                                     size=size, color=color))
    obs = os.path.join(run_dir, "observables.csv")
    if os.path.isfile(obs):
        steps, phi = read_observables(obs)
        fig = polar_order_figure(steps, phi, params, last.dim, last.n, last.box_lengths, theme=theme)
        written.append(house.save(fig, os.path.join(run_dir, f"polar_order.{fmt}"), dpi=dpi))
    return written


def after_run(run_dir: str, plots: bool = True, movie: bool = False, quiet: bool = False,
              theme: str = "dark", dpi=None, fmt: str = "png", color: str = "auto") -> None:
    """What ``flocking run`` does when a run ends: pictures unless ``plots=False``, a movie if asked."""
    import click

    if plots:
        written = write_plots(run_dir, theme=theme, dpi=dpi, fmt=fmt, color=color)
        if not quiet:
            click.echo(f"flocking: wrote {', '.join(os.path.basename(p) for p in written)}", err=True)
    if movie:
        path = write_movie(run_dir, os.path.join(run_dir, "movie.mp4"), theme=theme, progress=not quiet,
                           color=color)
        if not quiet:
            click.echo(f"flocking: wrote {path}", err=True)
