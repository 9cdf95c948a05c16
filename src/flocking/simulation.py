"""The simulation: a model, a state, a backend and the writers that record a run.

>>> import flocking
>>> sim = flocking.Simulation(flocking.Model(n=400, box=10.0, noise=0.2, seed=1))
>>> sim.run(50)
>>> sim.step, round(sim.polar_order[-1], 2) > 0.5
(50, True)
"""

from __future__ import annotations

import array
import json
import os
import sys
from typing import Any

import numpy as np

from . import backends
from .files import replace_atomically
from .model import Model, ParameterError
from .observables import extra_names, extra_observables
from .state import State

#: Polar order is handed to writers at least this often (particle-steps), so that a long
#: run without frames still reports progress and reacts to a stop request.
_CHUNK_WORK = 2_000_000


class NonFiniteError(RuntimeError):
    """The state became NaN or infinite: only a state given from outside, with headings
    far from unit length, can do that (a validated model keeps a state of unit headings
    finite). The message is one line."""


class Simulation:
    """Runs a :class:`Model` from a :class:`State` on a backend.

    ``state`` defaults to :meth:`State.random`; ``"random"`` or ``"aligned"`` asks for that
    state, which the ``cuda`` backend draws on the device (:func:`initial_state`). ``writers`` is a plain list of
    :class:`~flocking.writers.Writer` objects. ``polar_order`` holds the polar order of
    every step taken by this object (the initial state first), 8 bytes a step; with
    ``history=False`` it holds only the latest value, for runs of any length. ``origin`` is the step the
    whole run started from: writers' periods count from it, also after a resume.
    ``memory`` restores what a backend remembers beyond the state (the delay history),
    as saved in a checkpoint; other keywords go to the backend (``precision="float32"``
    for ``cuda``).

    The loop of :meth:`run`, in order:

    1. every writer's ``begin``, then ``write`` if the first step is due (it is, unless
       the run resumes between two triggers);
    2. the backend advances to the next step at which some writer is due (or a chunk of
       about two million particle-steps, or the end);
    3. writers ``observe`` the polar order of those steps (and the observables beyond it:
       :meth:`extra_observables`), then the due ones ``write``;
    4. a stop request (:meth:`request_stop`, e.g. from a signal handler) ends the run
       there, every writer writing that step; writers are closed at the end either way;
    5. a non-finite polar order ends the run with :class:`NonFiniteError`, after the
       writers have observed the steps before it.
    """

    def __init__(self, model: Model, state: State | None = None, backend: str = "cpu",
                 memory: dict[str, np.ndarray] | None = None, origin: int | None = None,
                 history: bool = True, **options: Any):
        self.model = model
        state = initial_state(model, state, backend)
        if isinstance(state, State):
            check_state(model, state)
        self.backend = backends.get(backend)(model, state, memory=memory, **options)
        self.backend_options = options
        self.writers: list = []
        first = state.polar_order() if isinstance(state, State) else self.backend.polar_order_now()
        self.polar_order = array.array("d", [first])
        self.history = history
        self.origin = (state.step if isinstance(state, State) else 0) if origin is None else int(origin)
        self.info: dict[str, Any] = {}
        self._stop = False
        self._extra_names = extra_names(model)

    @property
    def state(self) -> State:
        return self.backend.state

    @property
    def step(self) -> int:
        return self.backend.step

    @property
    def stopped(self) -> bool:
        """Whether the last :meth:`run` ended on a stop request."""
        return self._stop

    def parameters(self) -> dict[str, Any]:
        """What a file needs to describe this run: the model, the backend and ``info``."""
        return {"model": self.model.to_dict(), "backend": self.backend.name,
                "backend_options": self.backend_options, **self.info}

    def request_stop(self) -> None:
        """Stop the current run at the end of the step in progress (safe from a signal handler)."""
        self._stop = True

    def run(self, steps: int, progress: bool = False) -> None:
        """Take ``steps`` steps, calling the writers on their triggers."""
        self._stop = False
        last = self.step + int(steps)
        chunk = max(1, _CHUNK_WORK // self.model.n)
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=int(steps), unit="step", dynamic_ncols=True, leave=False)
        try:
            step = self.step
            for w in self.writers:
                w.begin(self)
                if w.due(step, self.origin, last):
                    w.write(self)
            while step < last and not self._stop:
                target = min(last, step + chunk, *(next_due(w, step, self.origin, last) for w in self.writers))
                phi = self.backend.advance(target - step)
                if not np.isfinite(phi).all():
                    self._non_finite(step, phi)
                if self.history:
                    self.polar_order.extend(phi)
                else:
                    self.polar_order[0] = phi[-1]
                done = np.arange(step + 1, target + 1)
                step = target
                extra = self.extra_observables(self.backend.moments) if self._extra_names else None
                for w in self.writers:
                    w.observe(done, phi, extra)
                    if w.due(step, self.origin, last) or self._stop:
                        w.write(self)
                if bar is not None:
                    bar.update(len(done))
        finally:
            if bar is not None:
                bar.close()
            errors = []
            for w in self.writers:  # every file closed, even if one fails
                try:
                    w.close()
                except Exception as err:  # noqa: PERF203
                    errors.append(err)
            if errors and sys.exc_info()[0] is None:
                raise errors[0]

    def extra_observables(self, moments: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The observables beyond the polar order (:func:`flocking.observables.extra_names`:
        per-species polar order, nematic order) from the backend's moment sums of some steps,
        or of the current state."""
        return extra_observables(self.model, None if moments is not None else self.state.headings, moments)

    def _non_finite(self, step: int, phi: np.ndarray) -> None:
        """Hand writers the finite steps of ``phi`` (which follow ``step``), then stop the run."""
        good = int(np.argmin(np.isfinite(phi)))
        if good:
            done = np.arange(step + 1, step + good + 1)
            for w in self.writers:
                w.observe(done, phi[:good])
        raise NonFiniteError(
            f"the run became non-finite at step {step + good + 1} (polar order {phi[good]}): a position or "
            f"heading is NaN or infinite; the files hold every step before it")

    # -- checkpoints ---------------------------------------------------------------------

    def save_checkpoint(self, path: str | os.PathLike) -> None:
        """Everything needed to continue bit for bit, written atomically (temp file, fsync, rename).

        Frames still being written are finished first: a checkpoint never gets ahead of
        the trajectory."""
        for w in self.writers:
            if hasattr(w, "sync"):
                w.sync()
        state = self.state
        meta = {"parameters": self.parameters(), "origin": self.origin, "step": state.step}
        arrays = {"positions": state.positions, "headings": state.headings, "speeds": state.speeds,
                  "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)}
        arrays.update({f"memory_{k}": v for k, v in self.backend.memory().items()})
        with replace_atomically(path, "wb") as f:
            np.savez(f, **arrays)

    @classmethod
    def load_checkpoint(cls, path: str | os.PathLike, history: bool = True) -> Simulation:
        """The simulation saved by :meth:`save_checkpoint` (writers are not saved)."""
        try:
            with np.load(os.fspath(path)) as data:
                meta = json.loads(data["meta"].tobytes().decode())
                memory = {k[len("memory_"):]: data[k] for k in data.files if k.startswith("memory_")}
                state = State(data["positions"], data["headings"], data["speeds"], meta["step"])
        except (OSError, ValueError, KeyError, EOFError) as err:
            raise ParameterError(f"resume: cannot read the checkpoint {os.fspath(path)!r} ({err})") from None
        params = meta["parameters"]
        sim = cls(Model.from_dict(params["model"]), state, params["backend"], memory=memory, origin=meta["origin"],
                  history=history, **params.get("backend_options", {}))
        sim.info = {k: v for k, v in params.items() if k not in ("model", "backend", "backend_options")}
        return sim


def initial_state(model: Model, state, backend: str):
    """The state a simulation starts from: ``state`` as given, :meth:`State.random` for
    ``None``, and for ``"random"`` or ``"aligned"`` the kind itself where the backend draws
    states where it runs (``cuda``: no array of N on the host), else that state drawn here."""
    if state is None:
        state = "random"
    if not isinstance(state, str):
        return state
    if state not in ("random", "aligned"):
        raise ParameterError(f"state: must be a State, 'random' or 'aligned' (got {state!r})")
    if getattr(backends.get(backend), "draws_states", False):
        return state
    return getattr(State, state)(model)


def check_state(model: Model, state: State) -> None:
    """Refuse a state of another size or dimension than the model's, or with NaN or
    infinite positions or headings."""
    if state.n != model.n or state.dim != model.dim:
        raise ValueError("state: its particle count or dimension differs from the model's")
    bad = np.count_nonzero(~np.isfinite(state.positions).all(axis=1) | ~np.isfinite(state.headings).all(axis=1))
    if bad:
        raise ParameterError(f"state: positions and headings must be finite ({bad} particles have NaN or "
                             "infinite ones)")


def next_due(writer, step: int, origin: int, last: int) -> int:
    """The next step after ``step`` (at most ``last``) at which ``writer`` is due: periods
    count from the run's ``origin``; a writer with ``every <= 0`` waits for ``last``."""
    if writer.every <= 0:
        return last
    return min(last, origin + ((step - origin) // writer.every + 1) * writer.every)
