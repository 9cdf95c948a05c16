"""Movies and the pictures a run leaves behind.

:func:`write_movie` streams frames from a trajectory through one reused :class:`Scene`
into H.264 (``.mp4``, the ffmpeg that ``imageio-ffmpeg`` ships) or a ``.gif`` (Pillow):
one frame in memory at a time for mp4. The file is written under a temporary name and
renamed at the end, so a failed or interrupted movie leaves nothing half-written.
:func:`after_run` is what ``flocking run`` calls when it is done.
"""

from __future__ import annotations

import csv
import os

import numpy as np

from ..model import ParameterError
from .colors import get_theme
from .render import Scene, check_style, polar_order_figure

FORMATS = (".mp4", ".gif")


def _open(trajectory):
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


def write_movie(trajectory, output, *, theme="dark", style="auto", fps=20.0, dpi=120, size=6.0,
                start=None, stop=None, stride=1, arrow_scale=1.0, time_label=True, rotate=False,
                azim=-60.0, elev=25.0, progress=False) -> str:
    """Write ``trajectory`` (a path, run folder or :class:`Trajectory`) to ``output``.

    ``output`` ends in ``.mp4`` (H.264) or ``.gif``. ``rotate`` turns a 3D camera once
    around the box over the movie. Returns the output path.
    """
    output = os.fspath(output)
    ext = os.path.splitext(output)[1].lower()
    if ext not in FORMATS:
        raise ParameterError(f"output: must end in .mp4 or .gif (got {output!r})")
    fps = float(fps)
    if not np.isfinite(fps) or not 0 < fps <= 240:
        raise ParameterError(f"fps: must be in (0, 240] (got {fps!r})")
    get_theme(theme)
    traj, owned = _open(trajectory)
    try:
        indices = select_frames(len(traj), start, stop, stride)
        first = traj[indices[0]]
        check_style(style, first.dim)
        scene = Scene.for_frame(first, traj.parameters, theme=theme, style=style, size=size, dpi=dpi,
                                arrow_scale=arrow_scale, time_label=time_label, azim=azim, elev=elev)
        turn = 360.0 / len(indices) if rotate else 0.0

        def frames():
            for k, i in enumerate(indices):
                frame = first if k == 0 else traj[i]
                yield scene.draw(frame, azim=azim + k * turn if rotate else None).rgb()

        from tqdm.auto import tqdm

        stream = tqdm(frames(), total=len(indices), unit="frame", disable=not progress,
                      desc=os.path.basename(output), dynamic_ncols=True, leave=False)
        folder = os.path.dirname(os.path.abspath(output))
        tmp = os.path.join(folder, f".{os.path.basename(output)}.part{ext}")
        try:
            (_write_mp4 if ext == ".mp4" else _write_gif)(tmp, stream, scene.pixels, fps)
            os.replace(tmp, output)
        finally:
            stream.close()
            if os.path.exists(tmp):
                os.remove(tmp)
    finally:
        if owned:
            traj.close()
    return output


def _write_mp4(path, frames, pixels, fps) -> None:
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(path, pixels, fps=fps, codec="libx264", quality=None,
                                         pix_fmt_out="yuv420p", macro_block_size=16,
                                         output_params=["-crf", "18", "-preset", "fast",
                                                        "-movflags", "+faststart"])
    writer.send(None)
    try:
        for rgb in frames:
            writer.send(np.ascontiguousarray(rgb))
    finally:
        writer.close()


def _write_gif(path, frames, pixels, fps) -> None:
    # GIF needs every frame before it is written; each is kept as 1 byte a pixel (palette)
    from PIL import Image

    images = [Image.fromarray(rgb).quantize(colors=255, method=Image.Quantize.FASTOCTREE) for rgb in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=1000.0 / fps, loop=0,
                   disposal=1)


def read_observables(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(steps, polar_order)`` columns of an ``observables.csv``."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = [(int(r["step"]), float(r["polar_order"])) for r in csv.DictReader(f)]
    steps, phi = zip(*rows) if rows else ((), ())
    return np.asarray(steps), np.asarray(phi)


def write_plots(run_dir: str, theme: str = "dark") -> list[str]:
    """``snapshot.png`` (last frame) and ``polar_order.png`` in ``run_dir``; their paths."""
    traj, _ = _open(run_dir)
    written = []
    with traj:
        last = traj[-1]
        params = traj.parameters
        scene = Scene.for_frame(last, params, theme=theme)
        path = os.path.join(run_dir, "snapshot.png")
        scene.draw(last).save(path)
        written.append(path)
    obs = os.path.join(run_dir, "observables.csv")
    if os.path.isfile(obs):
        steps, phi = read_observables(obs)
        fig = polar_order_figure(steps, phi, params, last.dim, last.n, last.box_lengths, theme=theme)
        path = os.path.join(run_dir, "polar_order.png")
        fig.savefig(path, facecolor=fig.get_facecolor())
        written.append(path)
    return written


def after_run(run_dir: str, plots: bool = True, movie: bool = False, quiet: bool = False) -> None:
    """What ``flocking run`` does when a run ends: pictures unless ``plots=False``, a movie if asked."""
    import click

    if plots:
        written = write_plots(run_dir)
        if not quiet:
            click.echo(f"flocking: wrote {', '.join(os.path.basename(p) for p in written)}", err=True)
    if movie:
        path = write_movie(run_dir, os.path.join(run_dir, "movie.mp4"), progress=not quiet)
        if not quiet:
            click.echo(f"flocking: wrote {path}", err=True)
