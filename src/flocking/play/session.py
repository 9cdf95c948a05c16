"""One live simulation per browser tab: control messages in, binary frames out.

A page talks to its :class:`Session` in small JSON objects, each with a ``type``:

=====================  =================================================================
``set``                ``{"type": "set", "params": {"noise": 2.5, ...}}``: model
                       parameters (:data:`PARAMS`). Changes that keep ``n``, ``density``
                       and ``dim`` continue from the current state; the others start a
                       new one.
``play`` ``pause``     run or stop the stream of steps
``step``               one step (while paused)
``reset``              a new initial state, ``{"type": "reset", "init": "aligned"}``
                       (``random`` by default)
``steps_per_frame``    ``{"type": "steps_per_frame", "value": 4}``: steps between frames
``config``             asks for the settings as a ``flocking run --config`` TOML file
=====================  =================================================================

Every message is checked before anything changes: size, JSON, the keys of its type, and
the parameters by building a :class:`~flocking.Model` and the limits of :func:`check_limits`.
A refused message leaves the simulation as it was and answers
``{"type": "error", "message": "..."}``. Accepted changes answer with ``{"type": "state",
...}`` so that the page shows what the server really runs.

Frames (:func:`encode_frame`) are little-endian: a 36-byte header (``b"FLK1"``, dim,
flags, 2 spare bytes, N as uint32, the step as float64, the polar order and the three box
lengths as float32), then the positions quantised to uint16 (``q = floor(x / L * 65536)``,
N x dim, particle order), then the headings: one uint8 angle per particle in 2D, an
azimuth and a ``z`` byte per particle in 3D.

>>> from flocking import Model
>>> s = Session(Model(n=100, box=8.0, noise=0.3, seed=1))
>>> [reply["type"] for reply in s.take_replies()]  # the page learns the settings first
['state']
>>> s.handle('{"type": "set", "params": {"noise": 9}}')
>>> s.take_replies()
[{'type': 'error', 'message': 'noise: must be in [0, 2*pi] for angular noise (got 9.0)'}]
>>> s.handle('{"type": "step"}')
>>> f = decode_frame(s.take_frame())
>>> f["step"], f["n"], f["positions"].shape
(1, 100, (100, 2))
"""

from __future__ import annotations

import collections
import json
import logging
import math
import struct
from typing import Any

import numba
import numpy as np

from ..config import RunConfig
from ..model import Model, ParameterError
from ..simulation import Simulation
from ..state import State, initial_speeds

#: Limits that keep one tab from taking the machine down.
MAX_N = 200_000
MAX_K = 64
MAX_DELAY = 100
MAX_STEPS_PER_FRAME = 50
MAX_MESSAGE = 4096  # characters of one control message
#: neighbour candidates visited per step (N times the particles in the 3^d cells around one)
MAX_WORK = 2e8
#: bytes of the delay ring buffer (delay x N x (d + 1) doubles)
MAX_DELAY_BYTES = 2**28

#: below this many particles a frame's steps run on one thread: a parallel step is then too
#: short to pay for waking threads, and far slower when other programs keep the cores busy
SERIAL_BELOW = 50_000

#: the model parameters a page may set (the box follows from n and density)
PARAMS = ("dim", "n", "density", "speed", "speeds", "neighbours", "radius", "k", "noise",
          "noise_type", "alignment", "delay", "dt", "update", "seed")
#: message type -> {field: (Python types, required)}
MESSAGES: dict[str, dict[str, tuple[tuple[type, ...], bool]]] = {
    "set": {"params": ((dict,), True)},
    "play": {},
    "pause": {},
    "step": {},
    "reset": {"init": ((str,), False)},
    "steps_per_frame": {"value": ((int,), True)},
    "config": {},
}
INITS = ("random", "aligned")

HEADER = struct.Struct("<4sBBHIdf3f")
MAGIC = b"FLK1"
RUNNING = 1  # flag bit


class ProtocolError(ValueError):
    """A control message that is not well formed; the text goes back to the page."""


def parse_message(raw: str | bytes) -> dict[str, Any]:
    """A checked control message, or :class:`ProtocolError` saying what is wrong.

    >>> parse_message('{"type": "pause"}')
    {'type': 'pause'}
    >>> parse_message('{"type": "pause", "now": true}')
    Traceback (most recent call last):
    ...
    flocking.play.session.ProtocolError: pause: unknown field 'now' (allowed: type)
    """
    if isinstance(raw, (bytes, bytearray)):
        raise ProtocolError("binary messages are not accepted; send a JSON object as text")
    if len(raw) > MAX_MESSAGE:
        raise ProtocolError(f"message too long ({len(raw)} characters; at most {MAX_MESSAGE})")
    try:
        msg = json.loads(raw, parse_constant=_no_constant)
    except (ValueError, RecursionError) as err:
        raise ProtocolError(f"not valid JSON ({err})") from None
    if not isinstance(msg, dict):
        raise ProtocolError(f"a message must be a JSON object with a 'type' (got {type(msg).__name__})")
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in MESSAGES:
        raise ProtocolError(f"type: must be one of {', '.join(MESSAGES)} (got {kind!r})")
    fields = MESSAGES[kind]
    for key in msg:
        if key != "type" and key not in fields:
            allowed = ", ".join(("type", *fields))
            raise ProtocolError(f"{kind}: unknown field {key!r} (allowed: {allowed})")
    for key, (types, required) in fields.items():
        if key not in msg:
            if required:
                raise ProtocolError(f"{kind}: missing field {key!r}")
        elif isinstance(msg[key], bool) or not isinstance(msg[key], types):
            raise ProtocolError(f"{kind}.{key}: must be a {types[0].__name__} (got {msg[key]!r})"[:300])
    return msg


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a number here")


def check_limits(model: Model) -> Model:
    """Refuse models that would take too much memory or time for an interactive page.

    >>> check_limits(Model(n=10**6, density=2.0))
    Traceback (most recent call last):
    ...
    flocking.model.ParameterError: n: must be at most 200000 in flocking play (got 1000000)
    """
    if model.n > MAX_N:
        raise ParameterError(f"n: must be at most {MAX_N} in flocking play (got {model.n})")
    if model.k > MAX_K:
        raise ParameterError(f"k: must be at most {MAX_K} in flocking play (got {model.k})")
    if model.delay > MAX_DELAY:
        raise ParameterError(f"delay: must be at most {MAX_DELAY} in flocking play (got {model.delay})")
    if model.delay * model.n * (model.dim + 1) * 8 > MAX_DELAY_BYTES:
        raise ParameterError(f"delay: {model.delay} steps of history for {model.n} particles is too "
                             f"much memory; lower delay or n")
    if model.neighbours == "metric":
        reach = min(model.n, model.density * (3.0 * model.radius) ** model.dim)
        if model.n * reach > MAX_WORK:
            raise ParameterError(f"radius: {model.radius:g} gives too many neighbours for {model.n} "
                                 f"particles at density {model.density:g}; lower radius, n or density")
    return model


class Session:
    """A simulation that a page steers: the model, the live state, and what to send back.

    The server calls :meth:`handle` for each message, :meth:`advance` while running, and
    sends :meth:`take_replies` and :meth:`take_frame`; nothing here touches a socket.
    """

    def __init__(self, model: Model, init: str = "random"):
        self.init = init
        self.running = True
        self.steps_per_frame = 1
        self.phi = 0.0
        self._replies: collections.deque[dict[str, Any]] = collections.deque(maxlen=64)
        self._dirty = True
        self._start(check_limits(model))
        self._replies.append(self.describe())

    # -- what the server calls ------------------------------------------------------------

    def handle(self, raw: str | bytes) -> None:
        """Apply one control message, or queue an error reply and change nothing."""
        try:
            msg = parse_message(raw)
            reply = getattr(self, "_on_" + msg["type"])(msg)
        except (ProtocolError, ParameterError) as err:
            self._replies.append({"type": "error", "message": str(err)})
            return
        except Exception as err:  # a bug must cost this message, not the server
            logging.getLogger("flocking.play").exception("control message failed: %.200r", raw)
            self._replies.append({"type": "error", "message": f"internal error ({type(err).__name__})"})
            return
        self._replies.append(reply or self.describe())

    def advance(self) -> None:
        """``steps_per_frame`` steps of the running simulation."""
        numba.set_num_threads(1 if self.model.n < SERIAL_BELOW else numba.config.NUMBA_NUM_THREADS)
        phi = self.sim.backend.advance(self.steps_per_frame)
        self.phi = float(phi[-1])
        self._dirty = True

    def take_replies(self) -> list[dict[str, Any]]:
        replies = list(self._replies)
        self._replies.clear()
        return replies

    def take_frame(self) -> bytes | None:
        """The current frame if anything changed since the last one, else ``None``."""
        if not self._dirty:
            return None
        self._dirty = False
        return encode_frame(self.sim.state, self.model, self.phi, self.running)

    @property
    def model(self) -> Model:
        return self.sim.model

    def describe(self) -> dict[str, Any]:
        """What the page shows in its controls."""
        return {"type": "state", "model": {**self.model.to_dict(), "density": self.model.density},
                "running": self.running, "steps_per_frame": self.steps_per_frame, "init": self.init,
                "limits": {"n": MAX_N, "k": MAX_K, "delay": MAX_DELAY,
                           "steps_per_frame": MAX_STEPS_PER_FRAME}}

    def config_toml(self) -> str:
        """The current parameters as a file that ``flocking run --config`` accepts."""
        cfg = RunConfig(self.model, init=self.init)
        return f"# exported from flocking play at step {self.sim.step}\n" + cfg.to_toml()

    # -- messages -----------------------------------------------------------------------

    def _on_set(self, msg: dict[str, Any]) -> None:
        changes = msg["params"]
        for key in changes:
            if key not in PARAMS:
                raise ProtocolError(f"set: unknown parameter {str(key)[:40]!r} (allowed: {', '.join(PARAMS)})")
        if not changes:
            return
        if {"n", "density", "dim"} & changes.keys():
            data = self.model.to_dict()
            del data["box"]
            data["density"] = self.model.density
            data.update(changes)
            self._start(check_limits(Model(**data)))
            return
        model = check_limits(self.model.replace(**changes))
        old = self.sim.state
        state = State(old.positions, old.headings, initial_speeds(model), old.step)
        self.sim = Simulation(model, state, backend="cpu")
        self._dirty = True

    def _on_play(self, msg: dict[str, Any]) -> None:
        self.running = True

    def _on_pause(self, msg: dict[str, Any]) -> None:
        self.running = False
        self._dirty = True  # the paused flag reaches the page with the next frame

    def _on_step(self, msg: dict[str, Any]) -> None:
        self.running = False
        steps, self.steps_per_frame = self.steps_per_frame, 1
        try:
            self.advance()
        finally:
            self.steps_per_frame = steps

    def _on_reset(self, msg: dict[str, Any]) -> None:
        init = msg.get("init", self.init)
        if init not in INITS:
            raise ProtocolError(f"reset.init: must be one of {', '.join(INITS)} (got {init[:40]!r})")
        self.init = init
        self._start(self.model)

    def _on_steps_per_frame(self, msg: dict[str, Any]) -> None:
        value = msg["value"]
        if not 1 <= value <= MAX_STEPS_PER_FRAME:
            raise ProtocolError(f"steps_per_frame: must be in [1, {MAX_STEPS_PER_FRAME}] (got {value})")
        self.steps_per_frame = value

    def _on_config(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"type": "config", "toml": self.config_toml(), "filename": "flocking-play.toml"}

    def _start(self, model: Model) -> None:
        state = State.aligned(model) if self.init == "aligned" else State.random(model)
        self.sim = Simulation(model, state, backend="cpu")
        self.phi = state.polar_order()
        self._dirty = True


# -- frames ------------------------------------------------------------------------------


def encode_frame(state: State, model: Model, phi: float, running: bool = True) -> bytes:
    """The binary frame of ``state`` (see the module docstring for the layout)."""
    n, dim = state.positions.shape
    box = np.asarray(model.box, dtype=np.float64)
    q = np.floor(state.positions * (65536.0 / box))
    positions = np.clip(q, 0, 65535).astype("<u2")
    h = state.headings
    azimuth = np.arctan2(h[:, 1], h[:, 0]) * (256.0 / (2.0 * math.pi))
    azimuth = np.round(azimuth).astype(np.int64) % 256
    if dim == 2:
        headings = azimuth.astype(np.uint8)
    else:
        z = np.round((np.clip(h[:, 2], -1.0, 1.0) + 1.0) * 127.5).astype(np.uint8)
        headings = np.stack([azimuth.astype(np.uint8), z], axis=1)
    lengths = (*model.box, 0.0) if dim == 2 else model.box
    header = HEADER.pack(MAGIC, dim, RUNNING if running else 0, 0, n, float(state.step), phi, *lengths)
    return header + positions.tobytes() + headings.tobytes()


def decode_frame(data: bytes) -> dict[str, Any]:
    """The inverse of :func:`encode_frame`, to quantisation (for tests and tools).

    Positions come back at the centres of their bins (error at most ``L / 131072``),
    headings as unit vectors.
    """
    magic, dim, flags, _, n, step, phi, *box = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ValueError("not a flocking play frame")
    box = np.array(box[:dim])
    offset = HEADER.size
    q = np.frombuffer(data, "<u2", n * dim, offset).reshape(n, dim)
    offset += 2 * n * dim
    raw = np.frombuffer(data, np.uint8, n * (dim - 1), offset).reshape(n, dim - 1)
    angle = raw[:, 0] * (2.0 * math.pi / 256.0)
    if dim == 2:
        headings = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    else:
        z = raw[:, 1] / 127.5 - 1.0
        rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        headings = np.stack([rho * np.cos(angle), rho * np.sin(angle), z], axis=1)
    return {"dim": dim, "n": n, "step": int(step), "phi": phi, "running": bool(flags & RUNNING),
            "box": box, "positions": (q + 0.5) * (box / 65536.0), "headings": headings}
