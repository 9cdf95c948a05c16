"""A complete run: the model plus how long, how often to record, where to start, which backend.

This is what ``config.toml`` holds, flat, with the command line's names (underscores for
dashes). Layers, lowest first: defaults, the parameters stored in an ``init`` trajectory,
a config file, and the options given on the command line.

>>> cfg = RunConfig.from_dict({"n": 100, "box": 10, "steps": 5, "noise": 0.2})
>>> RunConfig.from_toml(cfg.to_toml()) == cfg
True
>>> RunConfig.from_dict({"stesp": 5})
Traceback (most recent call last):
...
flocking.checks.ParameterError: stesp: unknown parameter; did you mean 'steps'?
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

from . import backends
from .checks import ParameterError, check_keys, integer
from .model import MODEL_KEYS, Model, dumps_toml, loads_toml
from .state import State

RUN_DEFAULTS = {"steps": 1000, "every": 10, "checkpoint_every": 1000, "init": "random", "backend": "cpu",
                "precision": "float64", "fields": 0.0, "fields_every": 0}
RUN_KEYS = MODEL_KEYS + tuple(RUN_DEFAULTS)
INITS = ("random", "aligned")


@dataclasses.dataclass(frozen=True)
class RunConfig:
    model: Model
    steps: int = RUN_DEFAULTS["steps"]
    every: int = RUN_DEFAULTS["every"]
    checkpoint_every: int = RUN_DEFAULTS["checkpoint_every"]
    init: str = RUN_DEFAULTS["init"]
    backend: str = RUN_DEFAULTS["backend"]
    precision: str = RUN_DEFAULTS["precision"]
    fields: float = RUN_DEFAULTS["fields"]  # bin size of the coarse-grained fields, 0: none
    fields_every: int = RUN_DEFAULTS["fields_every"]  # 0: as every

    def __post_init__(self) -> None:
        object.__setattr__(self, "steps", integer("steps", self.steps, 0))
        object.__setattr__(self, "every", integer("every", self.every, 0))
        object.__setattr__(self, "checkpoint_every", integer("checkpoint_every", self.checkpoint_every, 0))
        if not isinstance(self.init, str):
            raise ParameterError(f"init: must be 'random', 'aligned' or a .gsd file (got {self.init!r})")
        if self.init not in INITS and not os.path.isfile(self.init):
            raise ParameterError(f"init: must be 'random', 'aligned' or an existing .gsd file (got {self.init!r})")
        if self.precision not in ("float64", "float32"):
            raise ParameterError(f"precision: must be 'float64' or 'float32' (got {self.precision!r})")
        if self.precision == "float32" and self.backend != "cuda":
            raise ParameterError(f"precision: 'float32' needs the cuda backend (got backend {self.backend!r})")
        backends.get(self.backend)  # refuses unknown or unavailable backends
        if self.model.neighbours == "voronoi":  # docs/voronoi.md
            if self.backend == "cuda":
                raise ParameterError("neighbours: the cuda backend has no 'voronoi' neighbours: use 'cpu'")
            if self.backend == "cpu":
                from .backends.delaunay import qhull

                qhull()  # refuses, in one line, a machine without scipy
        object.__setattr__(self, "fields_every", integer("fields_every", self.fields_every, 0))
        if self.fields != 0:
            from .fields import Grid

            Grid.of(self.model, self.fields)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        check_keys(data, RUN_KEYS)
        run = {k: data[k] for k in RUN_DEFAULTS if k in data}
        model = Model(**{k: v for k, v in data.items() if k not in RUN_DEFAULTS})
        return cls(model, **run)

    @classmethod
    def from_layers(cls, *layers: dict[str, Any]) -> RunConfig:
        """Merge mappings, later ones winning; an ``init`` trajectory adds its own
        parameters (or at least its dimension, size and box) just below the file layers."""
        merged: dict[str, Any] = {}
        for layer in layers:
            check_keys(layer, RUN_KEYS)
            merged.update({k: v for k, v in layer.items() if v is not None})
        init = merged.get("init")
        if init not in (None, *INITS):
            base = init_parameters(init)
            if {"n", "density", "box"} & merged.keys():
                for key in ("n", "box"):
                    base.pop(key, None)
            merged = {**base, **merged}
        return cls.from_dict(merged)

    @classmethod
    def from_toml(cls, text: str, source: str = "config") -> RunConfig:
        return cls.from_dict(loads_toml(text, source))

    @classmethod
    def load(cls, path: str | os.PathLike) -> dict[str, Any]:
        """The raw mapping of a config file (validated keys), to be layered."""
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as err:
            raise ParameterError(f"config: cannot read {os.fspath(path)!r} ({err.strerror})") from None
        data = loads_toml(text, f"config {os.fspath(path)!r}")
        check_keys(data, RUN_KEYS)
        return data

    def to_dict(self) -> dict[str, Any]:
        init = self.init if self.init in INITS else os.path.abspath(self.init)
        fields = {"fields": float(self.fields)} if self.fields else {}
        if self.fields_every:  # kept without fields too, so that the file gives back this config
            fields["fields_every"] = self.fields_every
        return {**self.model.to_dict(), "steps": self.steps, "every": self.every,
                "checkpoint_every": self.checkpoint_every, "init": init, "backend": self.backend,
                "precision": self.precision, **fields}

    def to_toml(self) -> str:
        return "# flocking run configuration: flocking run --config THIS_FILE repeats the run\n" + dumps_toml(
            self.to_dict())

    def check_memory(self, available: int | None = None, device_free: int | None = None) -> None:
        """Refuse, with an estimate and the largest N that fits, a run that would not fit in
        the available memory: the backend's, plus the trajectory writer's copy of a frame (24
        bytes a particle); with the cuda backend, also what the card needs against its free
        memory (``device_free``, by default the card's: :mod:`flocking.backends.sizes`)."""
        from .backends.sizes import check_device, check_host

        need = backends.get(self.backend).bytes_needed(self.model) + 24 * self.model.n
        check_host(self.model, need, available_memory() if available is None else available, self.backend)
        if self.backend == "cuda":
            check_device([self.model], self.precision, free=device_free)

    def backend_options(self) -> dict[str, Any]:
        """Keyword arguments of the backend beyond the model (only what differs from defaults)."""
        return {"precision": self.precision} if self.precision != "float64" else {}

    def initial_state(self) -> State:
        if self.init == "random":
            return State.random(self.model)
        if self.init == "aligned":
            return State.aligned(self.model)
        return State.from_gsd(self.init, self.model)


def init_parameters(path: str) -> dict[str, Any]:
    """The model parameters of the run that wrote ``path`` (for a foreign file: its
    dimension, particle count and box)."""
    from .trajectory import open as open_trajectory

    if not os.path.isfile(path):
        raise ParameterError(f"init: must be 'random', 'aligned' or an existing .gsd file (got {path!r})")
    try:
        with open_trajectory(path) as traj:
            params = traj.parameters
            frame = traj[-1]
    except Exception as err:  # gsd raises several kinds on corrupt files
        raise ParameterError(f"init: cannot read a frame from {path!r} ({err})") from None
    if params is not None:
        return dict(params["model"])
    return {"dim": frame.dim, "n": frame.n, "box": frame.box_lengths.tolist()}


def available_memory() -> int:
    """Bytes of memory available to a new allocation (MemAvailable), or 0 if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 0
