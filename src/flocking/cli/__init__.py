"""The ``flocking`` command: one module per subcommand, errors as one line.

Every subcommand raises :class:`~flocking.model.ParameterError` (or
:class:`click.UsageError`) for bad input; :class:`Main` turns it into ``Error: ...`` on
stderr and exit code 2, with no traceback, before anything is written.
"""

from __future__ import annotations

import sys

import click

from ..model import ParameterError


class Main(click.Group):
    """A click group that reports our errors in one line."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except ParameterError as err:
            click.echo(f"Error: {option_name(str(err))}", err=True)
            ctx.exit(2)
        except OSError as err:
            click.echo(f"Error: {err.strerror or err}: {err.filename or ''}".rstrip(": "), err=True)
            ctx.exit(1)


def option_name(message: str) -> str:
    """``noise_type: ...`` -> ``--noise-type: ...``, so errors name the option as typed."""
    key, sep, rest = message.partition(": ")
    if sep and key.replace("_", "").isalnum() and " " not in key:
        return f"--{key.replace('_', '-')}: {rest}"
    return message


@click.group(cls=Main, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="flocking")
def main() -> None:
    """Simulate and analyse the Vicsek family of flocking models."""


def _register() -> None:
    from .run import run

    main.add_command(run)
    from .bench import bench

    main.add_command(bench)


_register()

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
