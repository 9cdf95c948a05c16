"""The web app of ``flocking play``: the page, its static files and one socket per tab.

``GET /`` serves ``static/index.html``; ``/static/...`` the scripts and styles; the page
opens ``/ws``, a WebSocket on which it sends JSON control messages and receives binary
frames (see :mod:`flocking.play.session`).

Each socket gets its own :class:`~flocking.play.session.Session` and two tasks. One
receives messages and hands them to the session, which checks them at once; the other is
the only one that touches the simulation and the only one that sends: in a worker thread
it applies what was received and takes a frame's steps (:meth:`Session.work`), then sends
the replies and the frame, at most ``fps`` frames a second. When the tab closes, the
session is closed (its steps stop within one step) and the stepping task cancelled.

All tabs share one :class:`~flocking.play.budget.Budget`: at most ``max_sessions`` tabs,
``memory`` bytes for all of them, and ``cores``: each running tab steps at most its equal
share, so its frames come at most as often as the estimated cost of a frame's steps
allows. A tab the budget cannot take waits up to :data:`ADMIT_SECONDS` for a closing tab
to give its share back (a tab closed and another reloaded at once reach the server in
either order), then is told why (``{"type": "refused", "message": ...}``) and its socket
closed with code 1013 ("try again later"); the server goes on.

A socket whose ``Origin`` is another site is refused, so a web page elsewhere cannot
drive the simulation on this machine.

numba compiles each kernel the first time it runs on a machine (then caches it), which
took about 21 s for the kernels of walls, obstacles, species and vision cones, and
longer on a busy machine: the first obstacle dropped froze the flock that long. So the
app compiles every kernel a page can switch to ahead, in a background thread, once per
process (:func:`warm_kernels`, over :func:`warm_models`; a second or so when they are
cached); and when a change still takes longer than :data:`BUSY_SECONDS` (the warm-up has
not reached it yet), the tab is told (``{"type": "busy", "message": ...}``) and says so
until its next frame comes.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import pathlib
import threading
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.responses import FileResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from ..model import Model, ParameterError
from ..state import State
from .budget import DEFAULT_MEMORY, Budget
from .session import Session, check_limits, check_step

STATIC = pathlib.Path(__file__).parent / "static"
#: the page needs nothing from elsewhere
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'",
    "Cache-Control": "no-cache",
}
TRY_LATER = 1013  # WebSocket close code: the server is busy, try again later
#: how long a new tab waits for memory or a place before it is refused, asking every
#: ADMIT_POLL seconds: a tab closed just before is given back within that
ADMIT_SECONDS, ADMIT_POLL = 2.0, 0.1
#: a change that takes longer than this is announced to its tab
BUSY_SECONDS = 1.0
BUSY_MESSAGE = ("Preparing these settings: the first use of walls, obstacles, a second species, a vision "
                "cone or k nearest neighbours compiles the simulation's code once on this machine (up to a "
                "minute or two); the flock goes on as soon as it is done.")
#: the background warm-up of :func:`warm_kernels` (one per process), once started
_warming: threading.Thread | None = None
_warming_lock = threading.Lock()


def create_app(model: Model, *, fps: float = 60.0, max_sessions: int = 16, memory: int = DEFAULT_MEMORY,
               cores: float | None = None) -> Starlette:
    """The Starlette app; every new tab starts from ``model`` (a random state).

    ``memory`` (bytes) and ``cores`` (default: numba's threads) are what all tabs share.
    """
    check_step(check_limits(model), State.random(model).positions, "radius" if model.neighbours == "metric" else "k")
    start_warming()
    budget = Budget(memory=memory, cores=cores, tabs=max_sessions)
    sessions: dict[Session, asyncio.Task] = {}  # each tab's session and its stepping task

    async def index(request):
        return FileResponse(STATIC / "index.html", headers=HEADERS)

    async def socket(ws: WebSocket) -> None:
        if not same_origin(ws.headers.get("origin"), ws.headers.get("host")):
            await ws.close(code=1008)
            return
        await ws.accept()
        session = await admit(model, budget)
        if isinstance(session, ParameterError):
            await ws.send_text(json.dumps({"type": "refused", "message": str(session)}))
            await ws.close(code=TRY_LATER)
            return
        wake = asyncio.Event()
        stepping = asyncio.create_task(stream(ws, session, wake, 1.0 / fps))
        sessions[session] = stepping
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                raw = message.get("text")
                if raw is None:
                    raw = message.get("bytes") or b""
                session.receive(raw)
                wake.set()
        except WebSocketDisconnect:
            pass
        finally:  # no await before the cleanup: this task may itself be cancelled
            session.close()
            del sessions[session]
            stepping.cancel()

    app = Starlette(routes=[
        Route("/", index),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
        WebSocketRoute("/ws", socket),
    ])
    app.state.sessions = sessions
    app.state.budget = budget
    return app


async def admit(model: Model, budget: Budget) -> Session | ParameterError:
    """A new tab's session, or the budget's refusal after :data:`ADMIT_SECONDS` of asking
    (a refused :class:`Session` costs nothing: the budget is asked first)."""
    loop = asyncio.get_running_loop()
    until = loop.time() + ADMIT_SECONDS
    while True:
        try:
            return await asyncio.to_thread(Session, model, budget=budget)
        except ParameterError as err:
            if loop.time() >= until:
                return err
        await asyncio.sleep(ADMIT_POLL)


async def stream(ws: WebSocket, session: Session, wake: asyncio.Event, period: float) -> None:
    """Apply messages and step while running, send replies and frames. Messages are
    applied at most once a ``period``, however fast they come; a frame's steps are taken
    when it is due: after ``period``, or longer to keep within the tab's share of the cores."""
    loop = asyncio.get_running_loop()
    due = apply = loop.time()
    while True:
        wake.clear()
        now = loop.time()
        step = session.running and now >= due
        if step or (session.pending() and now >= apply):
            try:
                work = asyncio.ensure_future(asyncio.to_thread(session.work, step))
                done, _ = await asyncio.wait({work}, timeout=BUSY_SECONDS)
                if not done:  # a tab that went away meanwhile is noticed at the next send
                    await send(ws, {"type": "busy", "message": BUSY_MESSAGE})
                await work
            except Exception as err:  # a bug costs this tab, not the server
                logging.getLogger("flocking.play").exception("a tab's simulation failed")
                if await send(ws, {"type": "refused", "message": f"internal error ({type(err).__name__}); "
                                                                  f"reload the page"}):
                    with contextlib.suppress(RuntimeError, OSError):
                        await ws.close(code=1011)
                return
            apply = now + period
            if step:
                due = now + max(period, session.frame_seconds / session.budget.share())
        for reply in session.take_replies():
            if not await send(ws, reply):
                return  # the tab went away; the receiving task ends the session
        frame = session.take_frame()
        if frame is not None and not await send(ws, frame):
            return
        wakes = [t for t, waiting in ((due, session.running), (apply, session.pending())) if waiting]
        timeout = max(0.0, min(wakes) - loop.time()) if wakes else None
        try:
            await asyncio.wait_for(wake.wait(), timeout)
        except TimeoutError:
            pass


async def send(ws: WebSocket, message: dict | bytes) -> bool:
    """Send a JSON reply or a frame; ``False`` if the tab has gone."""
    try:
        if isinstance(message, bytes):
            await ws.send_bytes(message)
        else:
            await ws.send_text(json.dumps(message))
    except (WebSocketDisconnect, RuntimeError, OSError):
        return False
    return True


def same_origin(origin: str | None, host: str | None) -> bool:
    """Accept clients that send no ``Origin`` (not a browser) or the page's own.

    >>> same_origin("http://127.0.0.1:8765", "127.0.0.1:8765"), same_origin("https://evil.example", "127.0.0.1:8765")
    (True, False)
    """
    if origin is None:
        return True
    try:
        return urlsplit(origin).netloc.lower() == (host or "").lower()
    except ValueError:
        return False


#: what a page switches on that needs a kernel of its own
#: (:func:`flocking.backends.cpu_kernels.variant`): walls, obstacles, chirality, species run
#: in the extended kernel; a vision cone, a coupling of species, and the two together each
#: in a weighted one; cohesion in its own (with a pair weight, in one more, compiled when
#: first asked for)
COUPLED = {"species": [{"fraction": 0.5}, {"fraction": 0.5}], "coupling": [[1.0, -1.0], [-1.0, 1.0]]}
PAGE_FEATURES = ({"obstacles": [{"centre": [4.0, 4.0], "radius": 1.0}]}, {"vision": 1.0}, COUPLED,
                 {"vision": 1.0, **COUPLED}, {"cohesion": 1.0})


def warm_models() -> list[Model]:
    """Small models whose first steps compile the kernels a page most often switches to:
    in 2D with metric neighbours, the plain model and each of :data:`PAGE_FEATURES`; with
    topological neighbours and in 3D, the plain and the extended model. The other options
    (delay, vectorial noise, walls, chirality, ...) and in 2D their combinations with each
    other and with a cone or a coupling run in one of these kernels; cohesion with a cone or
    a coupling, and combinations with topological neighbours or in 3D, compile when first
    asked for, and the page says so while they do."""
    small = {"n": 64, "box": 8.0}
    models = [Model(**small)] + [Model(**small, **extra) for extra in PAGE_FEATURES]
    for dim, neighbours in ((2, {"neighbours": "topological", "k": 7}), (3, {})):
        base = {"dim": dim, **small, **neighbours}
        models += [Model(**base), Model(**base, boundary="wall")]
    return models


def warm_kernels(models: list[Model] | None = None) -> None:
    """Take two steps of each of ``models`` (default :func:`warm_models`) on the cpu
    backend: numba compiles, or loads from its cache, what they run."""
    from ..simulation import Simulation

    for model in warm_models() if models is None else models:
        Simulation(model, backend="cpu").run(2)


def start_warming() -> threading.Thread:
    """:func:`warm_kernels` in a background thread, started by the first call in a process;
    the thread (a daemon: it never holds the server open)."""
    global _warming
    with _warming_lock:
        if _warming is None:
            _warming = threading.Thread(target=warm_kernels, name="flocking-play-warm-up", daemon=True)
            _warming.start()
        return _warming
