"""``flocking animate``: a movie of a run folder (or any GSD trajectory), or one frame as a picture."""

from __future__ import annotations

import os

import click

#: options that only a movie takes, and only a picture takes (with their defaults)
MOVIE_ONLY = {"start": None, "stop": None, "stride": None, "fps": None, "rotate": False}
PICTURE_ONLY = {"frame": None}


def size_value(text: str | None):
    """``--size``: a name (column, page, slide) or a width in inches."""
    if text is None:
        return 6.0
    try:
        return float(text)
    except ValueError:
        return text


@click.command()
@click.argument("run_dir", type=click.Path())
@click.option("--output", "-o", default=None,
              help="movie.mp4 (H.264), a .gif, or one frame as .png, .svg or .pdf. [default: RUN_DIR/movie.mp4]")
@click.option("--theme", default="dark", show_default=True, help="dark or light.")
@click.option("--style", default="auto", show_default=True,
              help="auto, arrows or density (2D), perspective (3D).")
@click.option("--color", default="auto", show_default=True,
              help="Colour particles by heading or species (auto: species when the run has several).")
@click.option("--fps", type=click.FLOAT, default=None, help="Movie: frames per second. [default: 20]")
@click.option("--dpi", type=click.FLOAT, default=None,
              help="Pixels per inch. [default: 120 for a movie, 200 for a picture]")
@click.option("--size", default=None, help="column, page, slide, or a width in inches. [default: 6]")
@click.option("--start", type=click.INT, default=None, help="Movie: first frame (index; negative from the end).")
@click.option("--stop", type=click.INT, default=None, help="Movie: stop before this frame index.")
@click.option("--stride", type=click.INT, default=None, help="Movie: every K-th frame. [default: 1]")
@click.option("--frame", type=click.INT, default=None, help="Picture: the frame index to draw. [default: -1, the last]")
@click.option("--arrow-scale", type=click.FLOAT, default=1.0, show_default=True,
              help="Arrow (3D: cone) length relative to the mean spacing.")
@click.option("--time-label/--no-time-label", default=True, show_default=True,
              help="Step and polar order in the corner.")
@click.option("--rotate", is_flag=True, help="Movie of a 3D run: turn the camera once around the box.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def animate(run_dir, output, quiet, size, **options):
    """Write a movie of RUN_DIR (a run folder or a .gsd file), streaming its frames, or
    draw one of its frames as a picture when --output ends in .png, .svg or .pdf.

    \b
    Examples:
      flocking animate runs/run-0001
      flocking animate runs/run-0001 --output flock.gif --stride 4 --size 4
      flocking animate big --style density --theme light --fps 30
      flocking animate run3d --rotate --output turn.mp4
      flocking animate runs/run-0001 -o last.pdf --theme light --size column
      flocking animate mixed --color heading
    """
    from ..model import ParameterError
    from ..viz import style
    from ..viz.movie import write_movie, write_picture

    if not os.path.exists(run_dir):
        raise ParameterError(f"no such run folder or trajectory: {run_dir!r}")
    if output is None:
        folder = run_dir if os.path.isdir(run_dir) else os.path.dirname(run_dir) or "."
        output = os.path.join(folder, "movie.mp4")
    ext = os.path.splitext(output)[1].lower().lstrip(".")
    picture = ext in style.FORMATS
    wrong = PICTURE_ONLY if not picture else MOVIE_ONLY
    given = [name for name, default in wrong.items() if options[name] != default]
    if given:
        kind = "a picture (.png, .svg or .pdf)" if not picture else "a movie (.mp4 or .gif)"
        raise ParameterError(f"{given[0]}: only {kind} takes --{given[0]} (got --output {output!r})")
    for name in wrong:
        options.pop(name)
    options["size"] = size_value(size)
    if picture:
        options["frame"] = -1 if options["frame"] is None else options["frame"]
        path = write_picture(run_dir, output, **options)
    else:
        options["fps"] = 20.0 if options["fps"] is None else options["fps"]
        options["stride"] = 1 if options["stride"] is None else options["stride"]
        options["dpi"] = 120.0 if options["dpi"] is None else options["dpi"]
        path = write_movie(run_dir, output, progress=not quiet, **options)
    if not quiet:
        click.echo(f"flocking: wrote {path}", err=True)
