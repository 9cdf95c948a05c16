"""The ``flocking`` command: one module per subcommand, errors as one line.

Every subcommand raises :class:`~flocking.model.ParameterError` (or a usage error of
click: an unknown option, a bad choice, a missing argument) for bad input; :class:`Main`
turns it into one line, ``Error: ...``, on stderr and exit code 2, with no traceback and no
usage block, before anything is written. The options every subcommand shares are in
:mod:`.options`.
"""

from __future__ import annotations

import difflib
import sys

import click

from ..model import ParameterError
from ..simulation import NonFiniteError
from .options import one_line

#: other spellings of a subcommand -> its name (accepted, not listed by ``--help``)
ALIASES = {"analyse": "analyze"}


class UsageLine(click.ClickException):
    """A usage error shown as click shows any of its errors, ``Error: ...``, on one line;
    exit code 2 like click's usage errors."""

    exit_code = 2


class Main(click.Group):
    """A click group that reports our errors and click's usage errors in one line, and
    accepts the spellings in :data:`ALIASES` without listing them twice in ``--help``."""

    def get_command(self, ctx, cmd_name):
        return super().get_command(ctx, ALIASES.get(cmd_name, cmd_name))

    def resolve_command(self, ctx, args):
        try:
            name, command, rest = super().resolve_command(ctx, args)
        except click.UsageError as err:
            close = difflib.get_close_matches(args[0], self.list_commands(ctx), n=1) if args else []
            hint = f"; did you mean {close[0]!r}?" if close else f" ({ctx.command_path} --help lists them)"
            raise click.UsageError(f"{err.message.rstrip('.')}{hint}", ctx) from None
        return (command.name if command else name), command, rest

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as err:
            raise usage_line(err) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as err:
            raise usage_line(err) from None
        except ParameterError as err:
            command = self.get_command(ctx, ctx.invoked_subcommand or "")
            params = command.params if command else []
            names = {o.lstrip("-").replace("-", "_") for p in params for o in p.opts if o.startswith("--")}
            click.echo(f"Error: {option_name(str(err), names)}", err=True)
            ctx.exit(2)
        except OSError as err:
            click.echo(f"Error: {err.strerror or err}: {err.filename or ''}".rstrip(": "), err=True)
            ctx.exit(1)
        except NonFiniteError as err:
            click.echo(f"Error: {err}", err=True)
            ctx.exit(1)


def usage_line(err: click.UsageError) -> click.ClickException:
    """``err`` as one line (:func:`.options.one_line`); the help that click shows when a
    command is given no arguments at all stays as it is."""
    if type(err).__name__ == "NoArgsIsHelpError":  # click >= 8.2
        return err
    return UsageLine(one_line(err))


def option_name(message: str, options: set[str] = frozenset()) -> str:
    """``noise_type: ...`` -> ``--noise-type: ...``: an error about a parameter names the
    option (of the running command, or of ``flocking run``) that sets it.

    >>> option_name("noise_type: must be one of 'angular', 'vectorial'")
    "--noise-type: must be one of 'angular', 'vectorial'"
    >>> option_name("nosie: unknown parameter")
    'nosie: unknown parameter'
    """
    from ..config import RUN_KEYS

    key, sep, rest = message.partition(": ")
    if key in ("obstacles", "species", "coupling"):  # lists and tables: a config file's keys, no option
        return message
    if sep and (key in options or key in RUN_KEYS or key in ("config", "out", "resume")):
        return f"--{key.replace('_', '-')}: {rest}"
    return message


@click.group("flocking", cls=Main, context_settings={"help_option_names": ["-h", "--help"]},
             epilog="Documentation: README.md and docs/ in the source tree (docs/model.md: the model and its "
                    "parameters). Every option of a command: flocking COMMAND --help.")
@click.version_option(package_name="flocking")
def main() -> None:
    """Simulate and analyse the Vicsek family of flocking models.

    \b
    Examples:
      flocking run                                  # 2048 particles, 1000 steps -> runs/run-0001
      flocking run --noise 2.5 --steps 5000 --out hot
      flocking run --obstacle 16,16,4 --boundary wall --out mill
      flocking animate hot                          # hot/movie.mp4
      flocking analyze hot                          # every measurement: JSON, CSV, figures
      flocking sweep examples/vicsek1995.toml       # a phase diagram: 192 runs
      flocking plot-sweep vicsek1995
      flocking play                                 # a live flock in the browser
    """


def _register() -> None:
    from .analyze import analyze
    from .animate import animate
    from .bench import bench
    from .compare import compare
    from .play import play
    from .run import run
    from .sweep import plot_sweep, sweep

    for command in (run, compare, animate, analyze, sweep, plot_sweep, play, bench):
        main.add_command(command)


_register()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
