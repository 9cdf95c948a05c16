"""Ensembles: many independent systems of one size, advanced together.

An :class:`Ensemble` holds ``R`` replicas that share the size and the geometry of the
model (:data:`flocking.backends.cuda.SHARED`: dimension, ``n``, box, radius, neighbour
rule, ``k``, noise type, update, ``dt``) and may each have their own seed, noise,
alignment, speed, speed rule and delay. With ``backend="cuda"`` all replicas live in one
set of device arrays and every step is one set of launches for all of them; each replica
still gives, bit for bit, what the same model gives alone on the ``cuda`` backend. Any
other backend runs one single-system backend per replica in turn (the same API without a
GPU, and the same numbers as those backends alone).

>>> import flocking
>>> base = flocking.Model(n=100, box=8.0, noise=1.0)
>>> ens = flocking.Ensemble([base.replace(seed=s, noise=eta) for s, eta in [(1, 0.5), (2, 3.0)]],
...                         backend="cpu")
>>> phi = ens.advance(20)
>>> phi.shape, ens.step, ens.states[1].n
((2, 20), 20, 100)

:func:`groups` splits any list of models into lists that can share an ensemble, which is
what a sweep over points and replicas needs: one ensemble per group, ``advance`` on each.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import backends
from .model import Model, ParameterError
from .observables import extra_names, extra_observables
from .simulation import Simulation, initial_state, next_due
from .state import State, frame_arrays


def groups(models: Sequence[Model]) -> list[list[int]]:
    """Indices of ``models`` in groups that can each run as one ensemble, in first-seen order.

    >>> a = Model(n=50, box=5.0, noise=1.0)
    >>> groups([a, a.replace(seed=3), a.replace(n=60), a.replace(noise=2.0)])
    [[0, 1, 3], [2]]
    """
    from .backends.cuda import ensemble_key  # numba.cuda is imported only where it is used

    found: dict[tuple, list[int]] = {}
    for i, model in enumerate(models):
        found.setdefault(ensemble_key(model), []).append(i)
    return list(found.values())


class Ensemble:
    """``R`` replicas (one per model) advanced together.

    ``states`` default to :meth:`State.random` of each model (drawn on the device with
    ``backend="cuda"``; ``"random"`` or ``"aligned"`` for every replica asks for those) and
    must all be at the same step; ``memories`` are what :meth:`memory` returned (the delay history), one per
    replica or ``None``. ``precision="float32"`` needs ``backend="cuda"``.
    """

    def __init__(self, models: Sequence[Model], states: Sequence[State] | None = None, backend: str = "cuda",
                 precision: str = "float64", memories: Sequence[dict | None] | None = None):
        from .backends.cuda import Engine, check_models

        models = list(models)
        check_models(models)
        if states is None:  # on the device where the replicas run there
            states = ["random"] * len(models) if backend == "cuda" else [State.random(m) for m in models]
        states = list(states)
        if memories is not None and len(memories) != len(models):
            raise ParameterError(f"memories: one per model ({len(models)}; got {len(memories)})")
        if precision != "float64" and backend != "cuda":
            raise ParameterError(f"precision: {precision!r} needs backend='cuda' (got backend={backend!r})")
        self.models = tuple(models)
        self.backend = backend
        self.precision = precision
        self.origin = states[0].step if states and isinstance(states[0], State) else 0
        self._states: list[State] | None = None
        if backend == "cuda":
            self._engine = Engine(models, states, memories, precision=precision)
            self._singles = None
            self._last = self._engine.polar_order_now()  # each replica's latest polar order
        else:
            cls = backends.get(backend)
            if len(states) != len(models):
                raise ParameterError(f"states: one per model ({len(models)}; got {len(states)})")
            states = [initial_state(m, s, backend) for m, s in zip(models, states)]
            if len({s.step for s in states}) != 1:
                raise ParameterError("states: replicas advance together, so they must all be at the same step")
            memories = memories or [None] * len(models)
            self._engine = None
            self._singles = [cls(m, s, memory=mem) for m, s, mem in zip(models, states, memories)]
            self._last = np.array([s.polar_order() for s in states])

    @property
    def replicas(self) -> int:
        return len(self.models)

    @property
    def step(self) -> int:
        return self._engine.step if self._engine is not None else self._singles[0].step

    def advance(self, steps: int) -> np.ndarray:
        """Take ``steps`` steps with every replica; the polar order after each, ``(R, steps)``."""
        self._states = None
        if self._engine is not None:
            phi = self._engine.advance(steps)
        else:
            phi = np.stack([b.advance(steps) for b in self._singles]) if steps else np.empty((self.replicas, 0))
        if steps:
            self._last = phi[:, -1].copy()
        return phi

    @property
    def states(self) -> list[State]:
        """Each replica's state, in particle-id order (copies, kept until the next step)."""
        if self._states is None:
            self._states = self._engine.states() if self._engine is not None else [b.state for b in self._singles]
        return self._states

    def memory(self) -> list[dict[str, np.ndarray]]:
        """Each replica's memory beyond its state, as its single-system backend's
        ``memory()`` (the delay ring): what a checkpoint of that replica holds."""
        if self._engine is not None:
            return self._engine.memory()
        return [b.memory() for b in self._singles]

    def _moments(self, r: int) -> np.ndarray:
        """Replica ``r``'s moment sums of the steps of the last :meth:`advance`."""
        return self._engine.moments[r] if self._engine is not None else self._singles[r].moments

    def replica(self, r: int) -> Replica:
        """Replica ``r`` as a writer sees a simulation (see :class:`Replica`)."""
        if not 0 <= r < self.replicas:
            raise ParameterError(f"replica: must be in [0, {self.replicas}) (got {r})")
        return Replica(self, r)

    def run(self, steps: int, writers: Sequence[Sequence[Any]] | None = None,
            infos: Sequence[dict[str, Any]] | None = None) -> np.ndarray:
        """Take ``steps`` steps, calling each replica's writers on their triggers, as
        :meth:`Simulation.run` does for one system: ``writers[r]`` is a list of writers
        (:class:`~flocking.GSDWriter`, :class:`~flocking.ObservablesWriter`,
        :class:`~flocking.CheckpointWriter`, ...) of replica ``r``. The ensemble advances to
        the next step at which any writer is due. ``infos[r]`` is what replica ``r``'s
        files record beyond its parameters (as :attr:`Simulation.info`). Returns the polar
        order ``(R, steps)``.
        """
        writers = [list(w) for w in writers] if writers is not None else [[] for _ in self.models]
        if len(writers) != self.replicas:
            raise ParameterError(f"writers: one list per replica ({self.replicas}; got {len(writers)})")
        views = [Replica(self, r, w) for r, w in enumerate(writers)]
        for view, info in zip(views, infos or ()):
            view.info = dict(info)
        everyone = [(view, w) for view in views for w in view.writers]
        # replicas with observables beyond the polar order (per species, nematic), from
        # the moment sums of their steps
        records_extra = [bool(extra_names(view.model)) for view in views]
        first = step = self.step
        last = first + int(steps)
        out = np.empty((self.replicas, int(steps)))
        try:
            for view, w in everyone:
                w.begin(view)
                if w.due(step, self.origin, last):
                    w.write(view)
            while step < last:
                target = min([last, *(next_due(w, step, self.origin, last) for _, w in everyone)])
                phi = self.advance(target - step)
                out[:, step - first:target - first] = phi
                done = np.arange(step + 1, target + 1)
                step = target
                extra = [view.extra_observables(self._moments(view.index)) if recorded else None
                         for view, recorded in zip(views, records_extra)]
                for view, w in everyone:
                    w.observe(done, phi[view.index], extra[view.index])
                    if w.due(step, self.origin, last):
                        w.write(view)
        finally:
            errors = []
            for _, w in everyone:  # every file closed, even if one fails
                try:
                    w.close()
                except Exception as err:  # noqa: PERF203
                    errors.append(err)
            if errors and sys.exc_info()[0] is None:
                raise errors[0]
        return out


class Replica:
    """One replica of an :class:`Ensemble`, seen as writers see a :class:`Simulation`:
    ``model``, ``step``, ``state``, ``origin``, ``polar_order`` (the latest value, as a
    simulation with ``history=False`` holds it), ``parameters()``, ``backend`` (with
    ``name``, ``memory()`` and ``frame_arrays()``) and :meth:`save_checkpoint`, whose file
    :meth:`Simulation.load_checkpoint` continues as a single system."""

    def __init__(self, ensemble: Ensemble, index: int, writers: Sequence[Any] = ()):
        self.ensemble, self.index = ensemble, index
        self.model = ensemble.models[index]
        self.writers = list(writers)
        self.info: dict[str, Any] = {}
        self.backend = self  # what writers ask a simulation's backend for is here

    @property
    def name(self) -> str:
        return self.ensemble.backend

    @property
    def origin(self) -> int:
        return self.ensemble.origin

    @property
    def step(self) -> int:
        return self.ensemble.step

    @property
    def state(self) -> State:
        return self.ensemble.states[self.index]

    @property
    def polar_order(self) -> list[float]:
        return [float(self.ensemble._last[self.index])]

    def memory(self) -> dict[str, np.ndarray]:
        return self.ensemble.memory()[self.index]

    def extra_observables(self, moments: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """As :meth:`Simulation.extra_observables`, for this replica."""
        return extra_observables(self.model, None if moments is not None else self.state.headings, moments)

    def frame_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Centred positions and velocities, float32 ``(N, 3)`` in id order (a GSD frame's)."""
        return frame_arrays(self.state, self.model.box)

    def fields(self, grid) -> np.ndarray:
        """This replica's field sums (``backend.fields``; on cuda binned on the device, all
        replicas in one launch)."""
        ens = self.ensemble
        if ens._engine is not None:
            return ens._engine.fields(grid)[self.index]
        return ens._singles[self.index].fields(grid)

    def parameters(self) -> dict[str, Any]:
        options = {"precision": self.ensemble.precision} if self.ensemble.backend == "cuda" else {}
        return {"model": self.model.to_dict(), "backend": self.ensemble.backend, "backend_options": options,
                **self.info}

    def save_checkpoint(self, path: str | os.PathLike) -> None:
        """This replica's checkpoint, in :meth:`Simulation.save_checkpoint`'s format."""
        Simulation.save_checkpoint(self, path)
