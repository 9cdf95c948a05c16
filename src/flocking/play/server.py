"""The web app of ``flocking play``: the page, its static files and one socket per tab.

``GET /`` serves ``static/index.html``; ``/static/...`` the scripts and styles; the page
opens ``/ws``, a WebSocket on which it sends JSON control messages and receives binary
frames (see :mod:`flocking.play.session`).

Each socket gets its own :class:`~flocking.play.session.Session` and two tasks: one
receives and applies control messages, the other steps the simulation and is the only
one that sends (replies first, then the frame), at most ``fps`` frames a second. An
``asyncio.Lock`` keeps a step and a parameter change from overlapping. When the tab
closes, the stepping task is cancelled and the session dropped.

A socket whose ``Origin`` is another site is refused, so a web page elsewhere cannot
drive the simulation on this machine; at most ``max_sessions`` tabs run at once.
"""

from __future__ import annotations

import asyncio
import json
import pathlib
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.responses import FileResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from ..model import Model
from .session import Session, check_limits

STATIC = pathlib.Path(__file__).parent / "static"
#: the page needs nothing from elsewhere
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'",
    "Cache-Control": "no-cache",
}


def create_app(model: Model, *, fps: float = 60.0, max_sessions: int = 16) -> Starlette:
    """The Starlette app; every new tab starts from ``model`` (a random state)."""
    check_limits(model)
    sessions: dict[Session, asyncio.Task] = {}  # each tab's session and its stepping task

    async def index(request):
        return FileResponse(STATIC / "index.html", headers=HEADERS)

    async def socket(ws: WebSocket) -> None:
        if not same_origin(ws.headers.get("origin"), ws.headers.get("host")):
            await ws.close(code=1008)
            return
        await ws.accept()
        if len(sessions) >= max_sessions:
            await ws.send_text(json.dumps({"type": "error", "message":
                                           f"too many open tabs (at most {max_sessions}); close one"}))
            await ws.close(code=1013)
            return
        session = Session(model)
        lock, wake = asyncio.Lock(), asyncio.Event()
        stepping = asyncio.create_task(stream(ws, session, lock, wake, 1.0 / fps))
        sessions[session] = stepping
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                raw = message.get("text")
                if raw is None:
                    raw = message.get("bytes") or b""
                async with lock:
                    await asyncio.to_thread(session.handle, raw)
                wake.set()
        except WebSocketDisconnect:
            pass
        finally:  # no await before the cleanup: this task may itself be cancelled
            del sessions[session]
            stepping.cancel()

    app = Starlette(routes=[
        Route("/", index),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
        WebSocketRoute("/ws", socket),
    ])
    app.state.sessions = sessions
    return app


async def stream(ws: WebSocket, session: Session, lock: asyncio.Lock, wake: asyncio.Event,
                 period: float) -> None:
    """Step while running, send replies and frames; wait for a message while paused."""
    loop = asyncio.get_running_loop()
    while True:
        start = loop.time()
        async with lock:
            if session.running:
                await asyncio.to_thread(session.advance)
            replies, frame = session.take_replies(), session.take_frame()
        try:
            for reply in replies:
                await ws.send_text(json.dumps(reply))
            if frame is not None:
                await ws.send_bytes(frame)
        except (WebSocketDisconnect, RuntimeError, OSError):
            return  # the tab went away; the receiving task ends the session
        if session.running:
            await asyncio.sleep(max(0.0, period - (loop.time() - start)))
        else:
            await wake.wait()
        wake.clear()


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
