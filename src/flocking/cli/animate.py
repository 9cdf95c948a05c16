"""``flocking animate``: a movie of a run folder (or any GSD trajectory)."""

from __future__ import annotations

import os

import click


@click.command()
@click.argument("run_dir", type=click.Path())
@click.option("--output", "-o", default=None,
              help="movie.mp4 (H.264) or a .gif. [default: RUN_DIR/movie.mp4]")
@click.option("--theme", default="dark", show_default=True, help="dark or light.")
@click.option("--style", default="auto", show_default=True,
              help="auto, arrows or density (2D), perspective (3D).")
@click.option("--fps", type=click.FLOAT, default=20.0, show_default=True, help="Frames per second.")
@click.option("--dpi", type=click.FLOAT, default=120.0, show_default=True, help="Pixels per inch.")
@click.option("--size", type=click.FLOAT, default=6.0, show_default=True, help="Width in inches.")
@click.option("--start", type=click.INT, default=None, help="First frame (index; negative from the end).")
@click.option("--stop", type=click.INT, default=None, help="Stop before this frame index.")
@click.option("--stride", type=click.INT, default=1, show_default=True, help="Every K-th frame.")
@click.option("--arrow-scale", type=click.FLOAT, default=1.0, show_default=True,
              help="Arrow length relative to the mean spacing.")
@click.option("--time-label/--no-time-label", default=True, show_default=True,
              help="Step and polar order in the corner.")
@click.option("--rotate", is_flag=True, help="3D: turn the camera once around the box.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def animate(run_dir, output, quiet, **options):
    """Write a movie of RUN_DIR (a run folder or a .gsd file), streaming its frames.

    \b
    Examples:
      flocking animate runs/run-0001
      flocking animate runs/run-0001 --output flock.gif --stride 4 --size 4
      flocking animate big --style density --theme light --fps 30
      flocking animate run3d --rotate --output turn.mp4
    """
    from ..model import ParameterError
    from ..viz.movie import write_movie

    if not os.path.exists(run_dir):
        raise ParameterError(f"no such run folder or trajectory: {run_dir!r}")
    if output is None:
        folder = run_dir if os.path.isdir(run_dir) else os.path.dirname(run_dir) or "."
        output = os.path.join(folder, "movie.mp4")
    path = write_movie(run_dir, output, progress=not quiet, **options)
    if not quiet:
        click.echo(f"flocking: wrote {path}", err=True)
