"""Backends: one step contract, several implementations.

A backend is built from ``(model, state, memory=None)`` and offers ``advance(steps)`` (take that many
steps, return the polar order after each), ``state`` (a copy, in particle-id order),
``step``, ``name``, ``memory()``: what it remembers beyond the state (the delay
history), which a checkpoint saves and ``memory=`` restores, and ``frame_arrays()``: the
centred positions and velocities a GSD frame holds, float32 ``(N, 3)`` in id order, valid
until the next ``advance`` (the CPU backend lends its spare buffers: a frame costs no
memory). Every backend draws the same counter-based random numbers, so from the same
state they take the same step to rounding.

>>> sorted(NAMES)
['cpu', 'cuda', 'reference']
"""

from __future__ import annotations

import importlib

from ..model import ParameterError

#: backend name -> (module, class)
NAMES = {
    "reference": ("flocking.backends.reference", "ReferenceBackend"),
    "cpu": ("flocking.backends.cpu", "CPUBackend"),
    "cuda": ("flocking.backends.cuda", "CUDABackend"),
}


def get(name: str):
    """The backend class called ``name``."""
    if not isinstance(name, str) or name not in NAMES:
        raise ParameterError(f"backend: must be one of {', '.join(map(repr, NAMES))} (got {name!r})")
    module, cls = NAMES[name]
    try:
        return getattr(importlib.import_module(module), cls)
    except ImportError as err:
        raise ParameterError(f"backend: {name!r} is not available here ({err})") from None
