"""``flocking animate``: a movie of a run folder (or any GSD trajectory), or one frame as a picture."""

from __future__ import annotations

import os

import click

from ..model import ParameterError
from . import options as opt

#: what ``--out`` may end in: a movie, or one frame as a picture
MOVIES = ("mp4", "gif")
#: options that only a movie takes, and only a picture takes (with their defaults)
MOVIE_ONLY = {"first_frame": None, "last_frame": None, "stride": None, "fps": None, "rotate": False}
PICTURE_ONLY = {"frame": None}


def frame_count(run_dir: str) -> int:
    """How many frames the trajectory of ``run_dir`` (a run folder or a GSD file) holds."""
    from ..trajectory import open as open_trajectory
    from .compare import trajectory_of

    path = trajectory_of(run_dir)
    try:
        with open_trajectory(path) as traj:
            return len(traj)
    except (OSError, RuntimeError, ValueError, KeyError) as err:  # gsd's ways of refusing a file
        raise ParameterError(f"RUN_DIR: cannot read the trajectory {path!r} ({err})") from None


def frame_index(option: str, index: int, count: int) -> int:
    """``index`` (negative: from the end) as an index in ``range(count)``, or refused.

    >>> frame_index("frame", -1, 10), frame_index("first_frame", 3, 10)
    (9, 3)
    >>> frame_index("frame", 10, 10)
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: frame: must be a frame index from -10 to 9 (the run has 10 frames; got 10)
    """
    if not -count <= index < count:
        raise ParameterError(f"{option}: must be a frame index from {-count} to {count - 1} (the run has {count} "
                             f"frames; got {index})")
    return index % count


@click.command(short_help="A movie of a run, or one frame as a picture.")
@click.argument("run_dir", type=click.Path())
@opt.out("A movie (.mp4, H.264, or .gif), or one frame as a picture (.png, .svg or .pdf): the extension "
         "decides.", "RUN_DIR/movie.mp4")
@opt.theme
@click.option("--style", type=opt.OneOf(("auto", "arrows", "density", "perspective")), default="auto",
              show_default=True, help="arrows or density (2D), perspective (3D); auto: arrows up to about 3e4 "
                                      "particles, then density.")
@opt.color
@opt.size
@opt.dpi("Pixels per inch.", "200 for a picture, 120 for a movie")
@click.option("--fps", type=click.FLOAT, default=None, help="Movie: frames per second.  [default: 20]")
@click.option("--first-frame", type=click.INT, default=None,
              help="Movie: the first frame (an index; negative from the end).  [default: 0, the first]")
@click.option("--last-frame", type=click.INT, default=None,
              help="Movie: the last frame (an index; negative from the end).  [default: -1, the last]")
@click.option("--stride", type=click.INT, default=None, help="Movie: every K-th frame.  [default: 1]")
@click.option("--frame", type=click.INT, default=None,
              help="Picture: the frame to draw (an index; negative from the end).  [default: -1, the last]")
@click.option("--arrow-scale", type=click.FLOAT, default=1.0, show_default=True,
              help="Arrow (3D: cone) length relative to the mean spacing.")
@click.option("--time-label/--no-time-label", default=True, show_default=True,
              help="Step and polar order in the corner.")
@click.option("--rotate", is_flag=True, help="Movie of a 3D run: turn the camera once around the box.")
@click.option("--from-fields", "fields", is_flag=True,
              help="Draw the coarse-grained fields (RUN_DIR/fields.nc, or RUN_DIR itself a .nc file) instead of "
                   "the particles: density as brightness, the local mean heading as hue.")
@opt.quiet("No progress bar.")
def animate(run_dir, out, quiet, first_frame, last_frame, fields, **options):
    """Write a movie of RUN_DIR (a run folder or a .gsd file), streaming its frames, or
    draw one of its frames as a picture when --out ends in .png, .svg or .pdf.

    \b
    Examples:
      flocking animate runs/run-0001
      flocking animate runs/run-0001 --out flock.gif --stride 4 --size column
      flocking animate big --style density --theme light --fps 30
      flocking animate run3d --rotate --out turn.mp4
      flocking animate runs/run-0001 -o last.pdf --theme light --size column
      flocking animate runs/run-0001 -o early.png --frame 10
      flocking animate mixed --color heading --first-frame 10 --last-frame -11
      flocking animate big --from-fields --out fields.mp4
    """
    from ..viz.movie import write_movie, write_picture

    if not os.path.exists(run_dir):
        raise ParameterError(f"RUN_DIR: no such run folder or trajectory: {run_dir!r}")
    if out is None:
        folder = run_dir if os.path.isdir(run_dir) else os.path.dirname(run_dir) or "."
        out = os.path.join(folder, "movie.mp4")
    ext = os.path.splitext(out)[1].lower().lstrip(".")
    if ext not in MOVIES + opt.FORMATS:
        raise ParameterError(f"out: must end in .mp4 or .gif (a movie), or .png, .svg or .pdf (one frame) "
                             f"(got {out!r})")
    picture = ext in opt.FORMATS
    options.update(first_frame=first_frame, last_frame=last_frame)
    wrong = PICTURE_ONLY if not picture else MOVIE_ONLY
    given = [name for name, default in wrong.items() if options[name] != default]
    if given:
        kind = "a picture (.png, .svg or .pdf)" if not picture else "a movie (.mp4 or .gif)"
        raise ParameterError(f"{given[0]}: only {kind} takes --{given[0].replace('_', '-')} (got --out {out!r})")
    for name in wrong:
        options.pop(name)
    opt.check_file("out", out)
    if fields or run_dir.endswith(".nc"):
        return draw_fields(run_dir, out, picture, quiet, first_frame, options)
    count = frame_count(run_dir)
    if picture:
        options["frame"] = frame_index("frame", -1 if options["frame"] is None else options["frame"], count)
        path = write_picture(run_dir, out, **options)
    else:
        first = frame_index("first_frame", options.pop("first_frame") or 0, count)
        last = frame_index("last_frame", -1 if options["last_frame"] is None else options["last_frame"], count)
        options.pop("last_frame")
        if last < first:
            raise ParameterError(f"last_frame: must not come before --first-frame (frames {first} and {last} of "
                                 f"{count})")
        options["fps"] = 20.0 if options["fps"] is None else options["fps"]
        options["stride"] = 1 if options["stride"] is None else options["stride"]
        options["dpi"] = 120.0 if options["dpi"] is None else options["dpi"]
        path = write_movie(run_dir, out, progress=not quiet, start=first, stop=last + 1, **options)
    if not quiet:
        click.echo(f"flocking: wrote {path}", err=True)


def draw_fields(run_dir: str, out: str, picture: bool, quiet: bool, first_frame, options: dict) -> None:
    """``flocking animate --from-fields``: a movie or one picture of the fields file."""
    from ..viz.fields import write_field_movie, write_field_picture

    if picture:
        frame = -1 if options["frame"] is None else options["frame"]
        path = write_field_picture(run_dir, out, frame=frame, theme=options["theme"], dpi=options["dpi"])
    else:
        last = options["last_frame"]
        path = write_field_movie(run_dir, out, theme=options["theme"], fps=options["fps"] or 20.0,
                                 dpi=options["dpi"] or 120.0, start=first_frame,
                                 stop=None if last is None or last == -1 else last + 1,
                                 stride=options["stride"] or 1, progress=not quiet)
    if not quiet:
        click.echo(f"flocking: wrote {path}", err=True)
