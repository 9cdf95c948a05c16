"""``flocking play``: the simulation live in the browser, for teaching and exploring."""

from __future__ import annotations

import socket
import webbrowser

import click

from ..model import DEFAULT_DENSITY, Model, ParameterError
from ..play.budget import DEFAULT_MEMORY, MiB
from .run import model_options

#: what a new tab shows unless options say otherwise: a flock that orders within seconds
PLAY_DEFAULTS = {"n": 4000, "density": DEFAULT_DENSITY, "noise": 1.0}
EXTRA = "flocking play needs its extra 'play': pip install '.[play]' in flocking's source folder"


@click.command(short_help="A live flock in the browser, with sliders.")
@model_options(defaults=PLAY_DEFAULTS)
@click.option("--host", default=None, metavar="ADDRESS",
              help="Address to listen on; anything but 127.0.0.1 lets other machines connect.  "
                   "[default: 127.0.0.1]")
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="Port to listen on; 0 picks a free one.")
@click.option("--no-browser", is_flag=True, help="Print the address instead of opening a browser.")
@click.option("--max-memory", type=click.IntRange(1), default=DEFAULT_MEMORY // MiB, show_default=True,
              metavar="MIB", help="Memory that all tabs share, in MiB; a tab or a model that does not fit is refused.")
def play(host, port, no_browser, max_memory, **options):
    """Run a flock on this machine and watch and steer it in the browser.

    Every browser tab gets its own simulation (the cpu backend); its sliders change the
    running simulation. The options set what a new tab starts with. Ctrl+C stops the
    server.

    \b
    Examples:
      flocking play
      flocking play --n 10000 --noise 2 --port 9000 --no-browser
      flocking play --dim 3 --neighbours topological
    """
    try:
        import uvicorn

        from ..play.server import create_app
    except ImportError:
        raise click.ClickException(EXTRA) from None
    host = host or "127.0.0.1"
    model = Model(**initial_parameters(options))
    app = create_app(model, memory=max_memory * MiB)  # refuses what a tab could not run
    sock = listen(host, port)
    address = sock.getsockname()
    url = f"http://{_url_host(address[0])}:{address[1]}/"
    click.echo(f"flocking play: {model} at {url} (Ctrl+C stops)", err=True)
    if host not in ("127.0.0.1", "localhost", "::1"):
        click.echo("flocking play: listening beyond this machine; anyone who can reach it can run flocks here",
                   err=True)
    if not no_browser:
        webbrowser.open(url)
    from uvicorn.config import WS_PROTOCOLS

    ws = "websockets-sansio" if "websockets-sansio" in WS_PROTOCOLS else "websockets"
    config = uvicorn.Config(app, ws=ws, ws_max_size=65536, log_level="warning", lifespan="off")
    try:
        uvicorn.Server(config).run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn has closed every tab; it raises the signal again
        pass
    click.echo("flocking play: stopped; goodbye", err=True)


def initial_parameters(options: dict) -> dict:
    """The model options given, over :data:`PLAY_DEFAULTS` (sizes only when none is given)."""
    given = {k: v for k, v in options.items() if v is not None}
    defaults = dict(PLAY_DEFAULTS)
    if {"n", "density", "box"} & given.keys():
        defaults.pop("n")
        if "box" in given and "n" in given:
            defaults.pop("density")
    return {**defaults, **given}


def listen(host: str, port: int) -> socket.socket:
    """A listening socket, or one clear line when the address is taken or not ours."""
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(64)
    except OSError as err:
        raise ParameterError(f"port: cannot listen on {host}:{port} ({err.strerror or err})") from None
    return sock


def _url_host(host: str) -> str:
    if host in ("0.0.0.0", "::"):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host else host
