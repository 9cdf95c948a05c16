"""The one vocabulary of the command line: each concept is one option, with one name, one
type and one default, in every subcommand that takes it.

========================  ==================  ==============================  ================
concept                   option              values                          default
========================  ==================  ==============================  ================
where the output goes     ``--out``, ``-o``   a folder (run, analyze, sweep,  a new folder, or
                                              bench) or a file (animate,      beside the input
                                              plot-sweep: its extension is
                                              its format)
format of pictures        ``--format``        png, svg, pdf                   png
theme                     ``--theme``         dark, light                     dark
size of figures           ``--size``          column, page, slide             page
resolution                ``--dpi``           10 to 1000 pixels per inch      200
colour of particles       ``--color``         auto, heading, species,         auto
                                              deviation
backend                   ``--backend``       cpu, cuda, reference            cpu
pictures or not           ``--plots``         ``--plots/--no-plots``          --plots
less output               ``--quiet``, ``-q`` a flag                          off
========================  ==================  ==============================  ================

The names of the choices are those of :mod:`flocking.viz` and :mod:`flocking.backends`
(``tests/test_cli_vocabulary.py`` checks that they agree); they are written out here so
that ``flocking --help`` does not import matplotlib.

Usage errors of every kind (a bad value, an unknown option, a missing argument) are one
line, ``Error: ...``, and exit code 2: see :func:`one_line`.
"""

from __future__ import annotations

import difflib
import errno
import os

import click

from ..model import ParameterError

THEMES = ("dark", "light")
SIZES = ("column", "page", "slide")
FORMATS = ("png", "svg", "pdf")
COLORS = ("auto", "heading", "species", "deviation")
BACKENDS = ("cpu", "cuda", "reference")
#: the resolutions a picture may have (:func:`flocking.viz.style.check_dpi`), pixels per inch
DPI_RANGE = (10, 1000)
#: what ``--size``, ``--theme``, ``--format`` and ``--dpi`` take when not given
DEFAULT_SIZE, DEFAULT_THEME, DEFAULT_FORMAT, DEFAULT_DPI = "page", "dark", "png", 200
#: the sizes in inches, for the help (:data:`flocking.viz.style.SIZES`)
SIZE_HELP = "column (3.4 in wide), page (7 in) or slide (8 x 4.5 in)"


class OneOf(click.Choice):
    """A choice among names, refused in the words of the project's own errors.

    >>> OneOf(["dark", "light"]).convert("neon", None, None)
    Traceback (most recent call last):
    ...
    click.exceptions.BadParameter: must be one of dark, light (got 'neon')
    """

    def convert(self, value, param, ctx):
        if value in self.choices:
            return value
        self.fail(f"must be one of {', '.join(self.choices)} (got {value!r})", param, ctx)


def _dpi(ctx, param, value):
    low, high = DPI_RANGE
    if value is not None and not low <= value <= high:  # NaN fails too
        raise click.BadParameter(f"must be in [{low}, {high}] (got {value})", ctx, param)
    return value


def out(help: str, default: str):
    """``--out``/``-o``: where the command writes; ``default`` says what it is when not given."""
    return click.option("--out", "-o", default=None, metavar="PATH", help=f"{help}  [default: {default}]")


def theme(func):
    """``--theme dark|light``."""
    return click.option("--theme", type=OneOf(THEMES), default=DEFAULT_THEME, show_default=True,
                        help="Pictures: dark for screens and slides, light for paper.")(func)


def size(func):
    """``--size column|page|slide``."""
    return click.option("--size", type=OneOf(SIZES), default=DEFAULT_SIZE, show_default=True,
                        help=f"Pictures: {SIZE_HELP}, with fonts to match.")(func)


def dpi(help: str = "Pictures: pixels per inch of a .png.", default: str = str(DEFAULT_DPI)):
    """``--dpi``, a number of pixels per inch in :data:`DPI_RANGE`."""
    return click.option("--dpi", type=click.FLOAT, default=None, callback=_dpi,
                        help=f"{help} From {DPI_RANGE[0]} to {DPI_RANGE[1]}.  [default: {default}]")


def picture_format(func):
    """``--format png|svg|pdf``: the pictures a command writes into a folder."""
    return click.option("--format", "fmt", type=OneOf(FORMATS), default=DEFAULT_FORMAT, show_default=True,
                        help="Pictures: file format (svg and pdf keep text and lines as vectors).")(func)


def color(func):
    """``--color auto|heading|species|deviation``."""
    return click.option("--color", type=OneOf(COLORS), default="auto", show_default=True,
                        help="Colour particles by heading, species, or (3D) the local heading's deviation "
                             "from the flock's (auto: species when the run has several, else heading in 2D "
                             "and deviation in 3D).")(func)


def backend(help: str, default: str = "cpu"):
    """``--backend cpu|cuda|reference``; ``None`` when not given (a config or sweep file
    may choose), ``default`` is what is used then."""
    return click.option("--backend", type=OneOf(BACKENDS), default=None,
                        help=f"{help}  [default: {default}]")


def plots(help: str, default: str = "--plots"):
    """``--plots/--no-plots``; ``None`` when not given."""
    return click.option("--plots/--no-plots", default=None, help=f"{help}  [default: {default}]")


def quiet(help: str = "No progress bar, no summary."):
    """``--quiet``/``-q``."""
    return click.option("--quiet", "-q", is_flag=True, default=False, help=help)


def check_folder(option: str, path: str) -> None:
    """Refuse, before anything is written, an output folder that cannot be made: one that is
    a file, or inside one (:class:`ParameterError`); one whose nearest existing parent is
    read-only or not ours to write in (the :class:`OSError` that making it would raise,
    which the command reports like a full disk).

    >>> import tempfile
    >>> notes = tempfile.NamedTemporaryFile(suffix=".txt")
    >>> check_folder("out", notes.name + "/run")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: out: cannot make '.../run': '...txt' is a file
    """
    if os.path.exists(path) and not os.path.isdir(path):
        raise ParameterError(f"{option}: {path!r} exists and is not a folder")
    parent = os.path.abspath(path)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise ParameterError(f"{option}: cannot make {path!r}: {parent!r} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        code = errno.EROFS if os.statvfs(parent).f_flag & os.ST_RDONLY else errno.EACCES
        raise OSError(code, os.strerror(code), parent)


def check_file(option: str, path: str) -> None:
    """Refuse an output file that is a folder, or whose folder does not exist or cannot be
    written (see :func:`check_folder`)."""
    if os.path.isdir(path):
        raise ParameterError(f"{option}: {path!r} is a folder; give a file name")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ParameterError(f"{option}: no folder {os.path.dirname(path)!r} to write {os.path.basename(path)!r} in")
    check_folder(option, folder)


def one_line(err: click.UsageError) -> str:
    """A usage error of click as one line, in the words of the project's own errors:
    ``--theme: 'neon' is not one of 'dark', 'light'.``; an unknown option with the closest
    ones click found."""
    if isinstance(err, click.NoSuchOption):
        known = [o for p in err.ctx.command.params for o in p.opts + p.secondary_opts] if err.ctx else []
        close = difflib.get_close_matches(err.option_name, known, n=1) or sorted(err.possibilities or ())[:1]
        hint = f"; did you mean {close[0]}?" if close else ""
        command = err.ctx.command_path if err.ctx is not None else "flocking"
        return f"{err.option_name}: no such option of {command}{hint} ({command} --help lists them)"
    if isinstance(err, click.BadParameter) and err.param is not None and not isinstance(err, click.MissingParameter):
        name = err.param.opts[0] if err.param.param_type_name == "option" else err.param.human_readable_name
        return f"{name}: {err.message}"
    return " ".join(err.format_message().split())
