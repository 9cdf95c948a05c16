"""The simulation: a model, a state, a backend and the writers that record a run.

>>> import flocking
>>> sim = flocking.Simulation(flocking.Model(n=400, box=10.0, noise=0.2, seed=1))
>>> sim.run(50)
>>> sim.step, round(sim.polar_order[-1], 2) > 0.5
(50, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import backends
from .model import Model
from .state import State

#: Polar order is handed to writers at least this often (particle-steps), so that a long
#: run without frames still reports progress and reacts to a stop request.
_CHUNK_WORK = 2_000_000


class Simulation:
    """Runs a :class:`Model` from a :class:`State` on a backend.

    ``state`` defaults to :meth:`State.random`. ``writers`` is a plain list of
    :class:`~flocking.writers.Writer` objects. ``polar_order`` holds the polar order of
    every step taken by this object (the initial state first).

    The loop of :meth:`run`, in order:

    1. every writer's ``begin``, then ``write`` for the first step;
    2. the backend advances to the next step at which some writer is due (or a chunk of
       about two million particle-steps, or the end);
    3. writers ``observe`` the polar order of those steps, then the due ones ``write``;
    4. a stop request (:meth:`request_stop`, e.g. from a signal handler) ends the run
       there, with the last frame written; writers are closed at the end either way.
    """

    def __init__(self, model: Model, state: State | None = None, backend: str = "cpu"):
        self.model = model
        state = State.random(model) if state is None else state
        if state.n != model.n or state.dim != model.dim:
            raise ValueError("state: its particle count or dimension differs from the model's")
        self.backend = backends.get(backend)(model, state)
        self.writers: list = []
        self.polar_order: list[float] = [state.polar_order()]
        self.info: dict[str, Any] = {}
        self._stop = False

    @property
    def state(self) -> State:
        return self.backend.state

    @property
    def step(self) -> int:
        return self.backend.step

    def parameters(self) -> dict[str, Any]:
        """What a file needs to describe this run: the model, the backend and ``info``."""
        return {"model": self.model.to_dict(), "backend": self.backend.name, **self.info}

    def request_stop(self) -> None:
        """Stop the current run at the end of the step in progress (safe from a signal handler)."""
        self._stop = True

    def run(self, steps: int, progress: bool = False) -> None:
        """Take ``steps`` steps, calling the writers on their triggers."""
        self._stop = False
        first = self.step
        last = first + int(steps)
        chunk = max(1, _CHUNK_WORK // self.model.n)
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=int(steps), unit="step", dynamic_ncols=True, leave=False)
        try:
            for w in self.writers:
                w.begin(self)
                w.write(self)
            step = first
            while step < last and not self._stop:
                target = min(last, step + chunk, *(_next_due(w, step, last) for w in self.writers))
                phi = self.backend.advance(target - step)
                self.polar_order.extend(phi.tolist())
                done = np.arange(step + 1, target + 1)
                step = target
                for w in self.writers:
                    w.observe(done, phi)
                    if w.due(step, first, last) or self._stop:
                        w.write(self)
                if bar is not None:
                    bar.update(len(done))
        finally:
            if bar is not None:
                bar.close()
            for w in self.writers:
                w.close()


def _next_due(writer, step: int, last: int) -> int:
    if writer.every <= 0:
        return last
    return min(last, (step // writer.every + 1) * writer.every)


__all__ = ["Simulation"]
