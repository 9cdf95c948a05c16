"""The ``flocking`` command: one module per subcommand, errors as one line.

Every subcommand raises :class:`~flocking.model.ParameterError` (or
:class:`click.UsageError`) for bad input; :class:`Main` turns it into ``Error: ...`` on
stderr and exit code 2, with no traceback, before anything is written.
"""

from __future__ import annotations

import sys

import click

from ..model import ParameterError
from ..simulation import NonFiniteError

#: other spellings of a subcommand -> its name (accepted, not listed by ``--help``)
ALIASES = {"analyse": "analyze"}


class Main(click.Group):
    """A click group that reports our errors in one line, and accepts the spellings in
    :data:`ALIASES` without listing them twice in ``--help``."""

    def get_command(self, ctx, cmd_name):
        return super().get_command(ctx, ALIASES.get(cmd_name, cmd_name))

    def resolve_command(self, ctx, args):
        name, command, rest = super().resolve_command(ctx, args)
        return (command.name if command else name), command, rest

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
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


@click.group(cls=Main, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="flocking")
def main() -> None:
    """Simulate and analyse the Vicsek family of flocking models."""


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
