"""One live simulation per browser tab: control messages in, binary frames out.

A page talks to its :class:`Session` in small JSON objects, each with a ``type``:

=====================  =================================================================
``set``                ``{"type": "set", "params": {"noise": 2.5, ...}}``: model
                       parameters (:data:`PARAMS`), the extensions among them
                       (``boundary``, ``obstacles``, ``species``, ``coupling``,
                       ``vision``, ``chirality``) under the names of
                       :class:`~flocking.Model`. Changes that keep ``n``, ``density``
                       and ``dim`` continue from the current state; the others start a
                       new one.
``obstacle``           ``{"type": "obstacle", "at": [x, y], "radius": 2.0}``: a click on
                       the flock, in box coordinates: removes the obstacle that holds
                       ``at``, or else adds one of ``radius`` centred there
``play`` ``pause``     run or stop the stream of steps
``step``               one step (while paused)
``reset``              a new initial state, ``{"type": "reset", "init": "aligned"}``
                       (``random`` by default)
``steps_per_frame``    ``{"type": "steps_per_frame", "value": 4}``: steps between frames
``config``             asks for the settings as a ``flocking run --config`` TOML file
=====================  =================================================================

The server hands each message to :meth:`Session.receive` as it arrives, which checks it
(size, JSON, the keys of its type, the parameters by building a :class:`~flocking.Model`
and the limits of :func:`check_limits`) and answers a refused one with ``{"type":
"error", "message": "..."}``, changing nothing (a refused ``set`` is followed by the state,
so that the page's controls go back to what runs). Accepted changes wait for the stepping
thread's next :meth:`Session.work`, which applies all of them at once: however many
``set`` messages came since the last frame, the simulation is rebuilt once, with the
latest value of each parameter, and pending steps before a ``reset`` are dropped. Then a
``{"type": "state", ...}`` reply says what the server really runs. So a flood of messages
costs their checks (about 0.1 ms each), not a rebuild each. Error replies beyond
:data:`MAX_ERRORS` per frame are counted in one last error; ``config`` answers are never
dropped silently.

Particles that a new obstacle covers are moved radially out to just beyond its rim (their
heading reflected if it pointed inward, as at a bounce): the engine requires every particle
outside every obstacle, and the model's own checks (obstacles a step apart and a step from
the walls) make that point free (:func:`clear_obstacles`). A change of dimension keeps the
walls of x and y (z is periodic) and drops the obstacles and, in 3D, the chirality.

Before a model runs, the cost of its step is estimated from where the particles are
(:meth:`~flocking.backends.cpu.CPUBackend.step_cost`), and again while it runs: a model whose step
would take more than :data:`MAX_STEP_SECONDS` is refused, and a flock that crowds until
its step would is paused with a message. So is a flock that turns non-finite. Steps are
taken one at a time, so a closed tab (:meth:`Session.close`) stops within one step.
Memory comes from the server's :class:`~flocking.play.budget.Budget`.

Frames are packed for the page by :mod:`.codec` (:func:`~.codec.encode_frame`).

>>> from flocking import Model
>>> s = Session(Model(n=100, box=8.0, noise=0.3, seed=1))
>>> [reply["type"] for reply in s.take_replies()]  # the page learns the settings first
['state']
>>> s.handle('{"type": "set", "params": {"noise": 9}}')
>>> [reply.get("message", reply["type"]) for reply in s.take_replies()]  # the state puts the slider back
['noise: must be in [0, 2*pi] for angular noise (got 9.0)', 'state']
>>> s.handle('{"type": "step"}')
>>> from flocking.play.codec import decode_frame
>>> f = decode_frame(s.take_frame())
>>> f["step"], f["n"], f["positions"].shape
(1, 100, (100, 2))
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import math
import sys
import threading
import time
import typing
from typing import Any

import numba
import numpy as np

from ..backends.cpu import CPUBackend
from ..config import RunConfig
from ..extensions import Obstacle
from ..model import Model, ParameterError
from ..simulation import Simulation
from ..space import Space
from ..state import State, initial_speeds
from .budget import Budget, session_bytes
from .codec import RUNNING, encode_frame

#: Limits that keep one tab from taking the machine down.
MAX_N = 200_000
MAX_K = 64
MAX_DELAY = 100
MAX_STEPS_PER_FRAME = 50
MAX_MESSAGE = 4096  # characters of one control message
#: bytes of the delay ring buffer (delay x N x (d + 1) doubles)
MAX_DELAY_BYTES = 2**28
#: vectorial noise above this is refused: at 10 the noise term is already ten times the
#: largest sum of headings it is added to
MAX_VECTORIAL_NOISE = 10.0
#: estimated seconds of one step (:meth:`~flocking.backends.cpu.CPUBackend.step_cost`); a model or a
#: flock that would step slower is refused or paused
MAX_STEP_SECONDS = 0.5
#: a running flock's step is priced again after this many seconds
PRICE_EVERY = 0.25
#: error replies kept per frame; the rest are counted in one more
MAX_ERRORS = 16
#: config answers that may wait; more are refused, with an error
MAX_CONFIGS = 16

#: below this many particles a frame's steps run on one thread: a parallel step is then too
#: short to pay for waking threads, and far slower when other programs keep the cores busy
SERIAL_BELOW = 50_000

def parallel_threads_are_safe() -> bool:
    """Whether numba has a threading layer that lets threads run parallel kernels at once
    (OpenMP or TBB). Without either (a machine without libgomp), it falls back to its
    workqueue layer, which aborts the process when two tabs step at the same time.

    >>> isinstance(parallel_threads_are_safe(), bool)
    True
    """
    for layer in ("omppool", "tbbpool"):
        try:
            importlib.import_module(f"numba.np.ufunc.{layer}")
            return True
        except ImportError:
            continue
    return False


#: held around every step where the threading layer cannot run two at once (tabs then take
#: turns); a lock that is never contended otherwise
STEP_LOCK: typing.ContextManager = threading.Lock() if not parallel_threads_are_safe() else contextlib.nullcontext()

#: obstacles a page may drop: each costs every particle a test every step
MAX_OBSTACLES = 32

#: the model parameters a page may set (the box follows from n and density)
PARAMS = ("dim", "n", "density", "speed", "speeds", "neighbours", "radius", "k", "noise",
          "noise_type", "alignment", "delay", "dt", "update", "seed",
          "boundary", "obstacles", "species", "coupling", "vision", "chirality", "cohesion")
#: message type -> {field: (Python types, required)}
MESSAGES: dict[str, dict[str, tuple[tuple[type, ...], bool]]] = {
    "set": {"params": ((dict,), True)},
    "play": {},
    "pause": {},
    "step": {},
    "reset": {"init": ((str,), False)},
    "steps_per_frame": {"value": ((int,), True)},
    "config": {},
    "obstacle": {"at": ((list,), True), "radius": ((float, int), True)},
}
INITS = ("random", "aligned")
#: the parameter a refusal names, first of those that changed: for a slow step, for memory
SLOW = ("radius", "k", "n", "density", "dim", "neighbours", "obstacles", "species", "coupling", "vision",
        "cohesion", "chirality", "boundary")
LARGE = ("n", "delay", "dim", "density", "speeds")

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
        raise ProtocolError(f"type: must be one of {', '.join(MESSAGES)} (got {str(kind)[:40]!r})")
    fields = MESSAGES[kind]
    for key in msg:
        if key != "type" and key not in fields:
            allowed = ", ".join(("type", *fields))
            raise ProtocolError(f"{kind}: unknown field {key[:40]!r} (allowed: {allowed})")
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
    """Refuse models too large for an interactive page, before anything is allocated.

    >>> check_limits(Model(n=10**6, density=2.0))
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: n: must be at most 200000 in flocking play (got 1000000)
    >>> check_limits(Model(n=100, box=10.0, speed=6.0))
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: speed: v0 dt must be at most half the box side, 5, in flocking play (got 6)
    """
    if model.n > MAX_N:
        raise ParameterError(f"n: must be at most {MAX_N} in flocking play (got {model.n})")
    if len(model.obstacles) > MAX_OBSTACLES:
        raise ParameterError(f"obstacles: at most {MAX_OBSTACLES} in flocking play (got {len(model.obstacles)}); "
                             f"click one to remove it")
    if model.k > MAX_K:
        raise ParameterError(f"k: must be at most {MAX_K} in flocking play (got {model.k})")
    if model.delay > MAX_DELAY:
        raise ParameterError(f"delay: must be at most {MAX_DELAY} in flocking play (got {model.delay})")
    if model.delay * model.n * (model.dim + 1) * 8 > MAX_DELAY_BYTES:
        raise ParameterError(f"delay: {model.delay} steps of history for {model.n} particles is too "
                             f"much memory; lower delay or n")
    if model.noise_type == "vectorial" and model.noise > MAX_VECTORIAL_NOISE:
        raise ParameterError(f"noise: must be at most {MAX_VECTORIAL_NOISE:g} for vectorial noise in "
                             f"flocking play (got {model.noise:g})")
    half = min(model.box) / 2
    if not model.speed * model.dt <= half:
        raise ParameterError(f"speed: v0 dt must be at most half the box side, {half:.3g}, in flocking play "
                             f"(got {model.speed * model.dt:.3g})")
    return model


def check_step(model: Model, positions: np.ndarray, name: str = "n") -> float:
    """The estimated seconds of a step from ``positions``, or a :class:`ParameterError`
    about parameter ``name`` if that is more than :data:`MAX_STEP_SECONDS`.

    >>> check_step(Model(n=6000, density=2.0, radius=30.0), np.full((6000, 2), 1.0), "radius")
    Traceback (most recent call last):
    ...
    flocking.checks.ParameterError: radius: one step would take about 0.9 s here (6000 neighbour candidates a particle; at most 0.5 s in flocking play); lower radius, n or density
    """
    seconds, candidates = CPUBackend.step_cost(model, positions)
    if seconds > MAX_STEP_SECONDS:
        lower = {"topological": "k or n", "voronoi": "n"}.get(model.neighbours, "radius, n or density")
        if model.extended:
            lower += ", or turn extensions off"
        raise ParameterError(f"{name}: one step would take about {seconds:.2g} s here ({candidates:.0f} "
                             f"neighbour candidates a particle; at most {MAX_STEP_SECONDS:g} s in flocking "
                             f"play); lower {lower}")
    return seconds


class Session:
    """A simulation that a page steers: the model, the live state, and what to send back.

    The server calls :meth:`receive` for each message (cheap, on its event loop), and
    from a worker thread :meth:`work`, which applies what was received and takes a
    frame's steps; it sends :meth:`take_replies` and :meth:`take_frame`, and calls
    :meth:`close` when the tab goes. ``budget`` is the server's; a session without one
    has no memory or tab limit. Nothing here touches a socket.
    """

    def __init__(self, model: Model, init: str = "random", budget: Budget | None = None):
        self.budget = budget or Budget(memory=sys.maxsize, tabs=sys.maxsize)
        self.init = init
        self.running = True
        self.steps_per_frame = 1
        self.closed = False
        self.broken: int | None = None  # the step at which the flock became non-finite
        self.step_seconds = 0.0  # the estimated cost of one step of the current flock
        self.frame_seconds = 0.0  # the estimated cost of the last frame's steps
        self._lock = threading.Lock()  # receive() and work() run on different threads
        self._replies: list[dict[str, Any]] = []
        self._refused = 0  # errors beyond MAX_ERRORS since the last take_replies
        self._configs = 0
        self._want_state = True
        self._frame: bytes | None = None
        model = check_limits(model)
        self.budget.join(self, session_bytes(model))  # first: a refused tab costs nothing
        try:
            state = self._new_state(model, init)
            self.step_seconds = check_step(model, state.positions)
            self.sim = Simulation(model, state, backend="cpu")
        except BaseException:
            self.budget.leave(self)
            raise
        self._model, self._step = model, state.step  # what runs, for the event loop's side
        self._priced = time.monotonic()
        self._target, self._reset, self._steps = model, None, 0  # what received messages ask for
        self.phi = state.polar_order()
        self._encode(state)

    @property
    def model(self) -> Model:
        """The model that runs (the event loop reads this while the simulation is rebuilt)."""
        return self._model

    # -- the event loop's side ------------------------------------------------------------

    def receive(self, raw: str | bytes) -> None:
        """Check one control message and queue what it asks, or queue an error reply."""
        try:
            msg = parse_message(raw)
            with self._lock:
                getattr(self, "_on_" + msg["type"])(msg)
        except (ProtocolError, ParameterError) as err:
            self._error(str(err))
        except Exception as err:  # a bug must cost this message, not the server
            logging.getLogger("flocking.play").exception("control message failed: %.200r", raw)
            self._error(f"internal error ({type(err).__name__})")

    def pending(self) -> bool:
        """Whether received messages wait for :meth:`work`."""
        return self._target is not self.model or self._reset is not None or self._steps > 0

    def take_replies(self) -> list[dict[str, Any]]:
        """Replies to send, in order; the ``state`` reply once nothing waits to be applied."""
        with self._lock:
            replies, self._replies, self._configs = self._replies, [], 0
            if self._refused:
                replies.append({"type": "error", "message": f"... and {self._refused} more messages were refused"})
                self._refused = 0
            if self._want_state and not self.pending():
                replies.append(self.describe())
                self._want_state = False
        return replies

    def take_frame(self) -> bytes | None:
        """The newest frame if there is one not yet taken, else ``None``."""
        with self._lock:
            frame, self._frame = self._frame, None
        if frame is None:
            return None
        flags = RUNNING if self.running else 0  # as it is now, not when the frame was made
        return frame[:5] + bytes([flags]) + frame[6:]

    def close(self) -> None:
        """The tab is gone: stop stepping (within one step) and give the memory back."""
        self.closed = True
        self.budget.leave(self)

    def describe(self) -> dict[str, Any]:
        """What the page shows in its controls."""
        return {"type": "state", "model": {**self.model.to_dict(), "density": self.model.density},
                "running": self.running, "steps_per_frame": self.steps_per_frame, "init": self.init,
                "species_counts": list(self.model.species_counts),
                # what the page draws: each obstacle and its periodic images that reach into the box
                "obstacle_images": Space.of(self.model).obstacle_images().tolist(),
                "limits": {"n": MAX_N, "k": MAX_K, "delay": MAX_DELAY,
                           "steps_per_frame": MAX_STEPS_PER_FRAME, "obstacles": MAX_OBSTACLES}}

    def config_toml(self, model: Model | None = None, init: str | None = None) -> str:
        """The parameters as a file that ``flocking run --config`` accepts."""
        cfg = RunConfig(model or self.model, init=init or self.init)
        return f"# exported from flocking play at step {self._step}\n" + cfg.to_toml()

    def _error(self, message: str) -> None:
        with self._lock:
            if sum(r["type"] == "error" for r in self._replies) < MAX_ERRORS:
                self._replies.append({"type": "error", "message": message[:300]})
            else:
                self._refused += 1

    # messages, checked against what earlier messages asked for (under the lock)

    def _on_set(self, msg: dict[str, Any]) -> None:
        changes = msg["params"]
        for key in changes:
            if key not in PARAMS:
                raise ProtocolError(f"set: unknown parameter {str(key)[:40]!r} (allowed: {', '.join(PARAMS)})")
        self._want_state = True
        if not changes:
            return
        target = self._target
        if "species" in changes and "coupling" not in changes and target.coupling is not None:
            count = len(changes["species"]) if isinstance(changes["species"], list) else -1
            if count != len(target.coupling):  # a matrix for other species cannot carry over
                changes = {**changes, "coupling": None}
        if {"n", "density", "dim"} & changes.keys():
            data = target.to_dict()
            del data["box"]
            data["density"] = target.density
            if changes.get("dim", target.dim) in (2, 3) and changes.get("dim", target.dim) != target.dim:
                data.update(_carry_across_dimensions(target, changes["dim"]))
            data.update(changes)
            self._target = check_limits(Model(**data))
        else:
            self._target = check_limits(target.replace(**changes))

    def _on_obstacle(self, msg: dict[str, Any]) -> None:
        target = self._target
        at = msg["at"]
        if len(at) != target.dim or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in at):
            raise ProtocolError(f"obstacle.at: must be {target.dim} numbers, a point in the box (got {at!r})"[:300])
        at = tuple(float(x) for x in at)
        obstacles = list(target.obstacles)
        hits = np.flatnonzero(Space.of(target).inside_each([at])[:, 0])
        if hits.size:
            del obstacles[hits[0]]
        else:
            obstacles.append(Obstacle(at, msg["radius"]))
        self._want_state = True
        self._target = check_limits(target.replace(obstacles=obstacles))

    def _check_finite(self, kind: str) -> None:
        target, model = self._target, self.model
        fresh = self._reset is not None or (target.n, target.dim, target.box) != (model.n, model.dim, model.box)
        if self.broken is not None and not fresh:
            raise ProtocolError(f"{kind}: the flock became non-finite at step {self.broken}; reset it first")

    def _on_play(self, msg: dict[str, Any]) -> None:
        self._check_finite("play")
        self.running = True
        self._want_state = True

    def _on_pause(self, msg: dict[str, Any]) -> None:
        self.running = False
        self._want_state = True

    def _on_step(self, msg: dict[str, Any]) -> None:
        self._check_finite("step")
        self.running = False
        self._want_state = True
        if self._steps >= MAX_STEPS_PER_FRAME:
            raise ProtocolError(f"step: {MAX_STEPS_PER_FRAME} steps are already waiting; this one is dropped")
        self._steps += 1

    def _on_reset(self, msg: dict[str, Any]) -> None:
        init = msg.get("init", self.init if self._reset is None else self._reset)
        if init not in INITS:
            raise ProtocolError(f"reset.init: must be one of {', '.join(INITS)} (got {init[:40]!r})")
        self._reset, self._steps = init, 0  # steps asked before a reset would be undone by it
        self._want_state = True

    def _on_steps_per_frame(self, msg: dict[str, Any]) -> None:
        value = msg["value"]
        if not 1 <= value <= MAX_STEPS_PER_FRAME:
            raise ProtocolError(f"steps_per_frame: must be in [1, {MAX_STEPS_PER_FRAME}] (got {value})")
        self.steps_per_frame = value
        self._want_state = True

    def _on_config(self, msg: dict[str, Any]) -> None:
        if self._configs >= MAX_CONFIGS:
            raise ProtocolError(f"config: {MAX_CONFIGS} answers are already waiting; ask again later")
        self._configs += 1
        self._replies.append({"type": "config", "toml": self.config_toml(self._target, self._reset),
                              "filename": "flocking-play.toml"})

    # -- the stepping thread's side -------------------------------------------------------

    def work(self, advance: bool = False) -> None:
        """Apply the messages received so far, then take the steps they asked for and, with
        ``advance`` while running, a frame's steps; the new frame is then ready."""
        with self._lock:
            target, reset, steps = self._target, self._reset, self._steps
            self._reset, self._steps = None, 0
        changed = (target is not self.model or reset is not None) and self._apply(target, reset)
        if advance and self.running:
            steps += self.steps_per_frame
        if steps and time.monotonic() - self._priced >= PRICE_EVERY:  # the flock may have crowded
            self.step_seconds = CPUBackend.step_cost(self.model, self.sim.state.positions)[0]
            self._priced = time.monotonic()
        done = self._advance(steps)
        if (changed or done) and self.broken is None:
            self._encode(self.sim.state)

    def handle(self, raw: str | bytes) -> None:
        """:meth:`receive` and :meth:`work` in one (for tests and scripts)."""
        self.receive(raw)
        self.work()

    def _apply(self, target: Model, reset: str | None) -> bool:
        """Run ``target`` (from a new state after a reset or a size change); on a refusal,
        queue the error and keep running what ran."""
        model = self.model
        changed = {k for k in PARAMS if getattr(target, k) != getattr(model, k)}
        fresh = reset is not None or (target.n, target.dim, target.box) != (model.n, model.dim, model.box)
        init = self.init if reset is None else reset
        try:
            if fresh:
                state = self._new_state(target, init)
            else:
                old = self.sim.state  # a copy, in particle-id order
                clear_obstacles(target, old.positions, old.headings)
                state = State(old.positions, old.headings, initial_speeds(target), old.step)
            seconds = check_step(target, state.positions, next((k for k in SLOW if k in changed), "n"))
            self.budget.reserve(self, session_bytes(target), next((k for k in LARGE if k in changed), "n"))
            if self.closed:  # the tab went while this was decided: hold nothing
                self.budget.leave(self)
                return False
        except ParameterError as err:
            self._error(str(err))
            self._want_state = True
            with self._lock:
                if self._target is target:  # else later messages asked for more: checked next time
                    self._target = model
            return False
        self.sim = None  # the old simulation's memory goes before the new one's comes
        self.sim = Simulation(target, state, backend="cpu")
        self._model, self._step = target, state.step
        self.init, self.step_seconds, self._priced = init, seconds, time.monotonic()
        if fresh:
            self.broken = None
        self.phi = state.polar_order()
        return True

    def _advance(self, steps: int) -> int:
        """Take up to ``steps`` steps, one at a time: stop when the tab closes, when new
        messages wait, or when the flock becomes too slow to step or non-finite."""
        if steps and self.step_seconds > MAX_STEP_SECONDS:
            self.running = False
            self._want_state = True
            self._error(f"the flock has crowded so that one step would take about {self.step_seconds:.2g} s (at "
                        f"most {MAX_STEP_SECONDS:g} s in flocking play); paused: reset it, or lower radius, n "
                        f"or density")
            return 0
        numba.set_num_threads(1 if self.model.n < SERIAL_BELOW else numba.config.NUMBA_NUM_THREADS)
        done = 0
        for _ in range(steps):
            if self.closed or (done and self.pending()):
                break
            with STEP_LOCK:
                phi = float(self.sim.backend.advance(1)[0])
            self._step += 1
            done += 1
            if not math.isfinite(phi):
                self.running = False
                self.broken = self._step
                self._want_state = True
                self._error(f"the flock became non-finite at step {self.broken} (phi = {phi}); paused: reset it")
                break
            self.phi = phi
        self.frame_seconds = done * self.step_seconds
        return done

    def _new_state(self, model: Model, init: str) -> State:
        return State.aligned(model) if init == "aligned" else State.random(model)

    def _encode(self, state: State) -> None:
        frame = encode_frame(state, self.model, self.phi, self.running)
        with self._lock:
            self._frame = frame


def _carry_across_dimensions(model: Model, dim: int) -> dict[str, Any]:
    """What of ``model``'s extensions a change to ``dim`` keeps: the walls of x and y (z
    periodic); obstacles (their centres have the old dimension) and, in 3D, the chirality
    (a turn in the plane) are dropped."""
    boundary = (*model.boundary[:2], "periodic")[:dim]
    changes: dict[str, Any] = {"boundary": ",".join(boundary), "obstacles": []}
    if dim == 3:
        changes["chirality"] = 0.0
    return changes


def clear_obstacles(model: Model, positions: np.ndarray, headings: np.ndarray) -> int:
    """Move the particles inside ``model``'s obstacles radially out to just beyond the rim
    (``a + 1e-6 v0 dt`` from the centre; a particle at the centre moves against its
    heading), reflecting a heading that points inward, as a bounce does. Changes the
    arrays in place and returns how many particles moved.

    The model guarantees that obstacles are a step apart and a step from the walls, so
    the new place is outside every obstacle and inside the walls.

    >>> from flocking import Model
    >>> model = Model(n=2, box=10.0, obstacles=[{"centre": [5.0, 5.0], "radius": 2.0}])
    >>> x, u = np.array([[5.5, 5.0], [9.0, 9.0]]), np.array([[-1.0, 0.0], [1.0, 0.0]])
    >>> clear_obstacles(model, x, u), x[0].round(5).tolist(), u[0].tolist()  # out to the right, turned round
    (1, [7.0, 5.0], [1.0, 0.0])
    """
    return Space.of(model).clear_obstacles(positions, headings, 1e-6 * model.max_speed * model.dt)
