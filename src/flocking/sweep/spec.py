"""The sweep file: a base run, a grid of parameters, replicas and a transient to discard.

A sweep file is TOML with three tables::

    [sweep]                 # how to sweep (all optional)
    seed = 1                # the sweep seed; every point's seed derives from it
    replicas = 4            # independent runs per grid point
    discard = 0.5           # transient: an integer is a number of steps, a float a fraction
    keep_trajectories = false
    time_series = false     # also store the polar order of every measured step

    [base]                  # any key of ``flocking run`` (config.toml), except seed
    density = 4.0
    speed = 0.03
    steps = 2000

    [grid]                  # every combination of these values is a point
    noise = {start = 0.0, stop = 5.0, num = 11}   # inclusive, like numpy.linspace
    n = [40, 100, 400]

A range may add ``scale = "log"`` (geometric spacing); integer parameters (``n``, ``k``,
``delay``, ``steps``, ...) are rounded to whole numbers.

Axes and fixed values. Every entry of ``[grid]`` is an axis: a list of values, one per
grid point. Every entry of ``[base]`` is one fixed value, whatever its type. The
parameters whose value is itself a list or a table (:data:`LIST_VALUED`: ``obstacles``,
``species``, ``coupling``, ``field``) therefore belong in ``[base]``; on a ``[grid]`` axis
each value must be a whole one (``field = [[1.0, 0.0], [0.0, 1.0]]`` sweeps two
directions), and a single one there is refused rather than read as an axis.

Seeds. The point ``p`` (a mapping of the swept values) of replica ``r`` in a sweep of seed
``S`` runs with ``point_seed(S, p, r)``: the first 8 bytes of the SHA-256 of the canonical
JSON text ``{"point": p, "replica": r, "seed": S}`` (sorted keys), as a little-endian
integer, shifted right by 11 bits (so it fits in ``[0, 2**53)``, which every backend takes). It depends on nothing
else: not on the order of the grid, on the other values swept or on the base.

>>> spec = SweepSpec.from_dict({"sweep": {"replicas": 2}, "base": {"n": 50, "density": 2.0, "steps": 10},
...                             "grid": {"noise": {"start": 0.0, "stop": 1.0, "num": 3}}})
>>> spec.shape, [p.params for p in spec.points()][:3]
((3, 2), [{'noise': 0.0}, {'noise': 0.0}, {'noise': 0.5}])
>>> point_seed(0, {"noise": 0.5}, 1) == spec.points()[3].config.model.seed
True
>>> SweepSpec.from_dict({"grid": {"nosie": [1.0]}})
Traceback (most recent call last):
...
flocking.checks.ParameterError: grid.nosie: unknown parameter; did you mean 'noise'?
>>> SweepSpec.from_dict({"base": {"n": 50, "box": 8.0}, "grid": {"field": [1.0, 0.0]}})
Traceback (most recent call last):
...
flocking.checks.ParameterError: grid.field: one value is a direction (a list), so an axis is a list of directions such as [[1.0, 0.0], [0.0, 1.0]]; a single value goes in [base] (got [1.0, 0.0])
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import numbers
import os
from typing import Any

from ..backends.cuda import check_supported
from ..config import RUN_DEFAULTS, RUN_KEYS, RunConfig
from ..checks import ParameterError, check_keys, integer
from ..model import loads_toml

SWEEP_DEFAULTS = {"seed": 0, "replicas": 1, "discard": 0.5, "keep_trajectories": False, "time_series": False}
TABLES = ("sweep", "base", "grid")
#: Parameters a grid may sweep and a base may set: everything but the seed, which derives.
PARAMETER_KEYS = tuple(k for k in RUN_KEYS if k != "seed")
#: Parameters held as whole numbers: ranges over them are rounded.
INTEGER_KEYS = ("dim", "n", "k", "delay", "steps", "every")
RANGE_KEYS = ("start", "stop", "num", "scale")
#: Parameters whose one value is a list or a table: fixed in [base], or an axis of whole
#: values in [grid] (parameter -> an example of such an axis).
LIST_VALUED = {"obstacles": "[[], [{centre = [8.0, 8.0], radius = 2.0}]]",
               "species": "[[{fraction = 0.5}, {fraction = 0.5, noise = 2.0}], [{fraction = 1.0}]]",
               "coupling": "[[[1.0, -1.0], [-1.0, 1.0]], [[1.0, 1.0], [1.0, 1.0]]]",
               "field": "[[1.0, 0.0], [0.0, 1.0]]"}


def point_seed(seed: int, params: dict[str, Any], replica: int) -> int:
    """The seed of one run: a pure function of the sweep seed, the swept values and the replica."""
    text = json.dumps({"point": params, "replica": int(replica), "seed": int(seed)}, sort_keys=True)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little") >> 11


@dataclasses.dataclass(frozen=True)
class Point:
    """One run of a sweep: its swept values, replica, grid index and full configuration."""

    params: dict[str, Any]
    replica: int
    index: tuple[int, ...]
    config: RunConfig
    discard: int

    @property
    def id(self) -> str:
        """A name for the point's files: a hash of everything that determines its result."""
        text = json.dumps({"config": self.config.to_dict(), "discard": self.discard}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def label(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.params.items()) + f", replica={self.replica}"


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: settings, base run, grid values (in file order)."""

    base: dict[str, Any]
    grid: dict[str, list]
    seed: int = 0
    replicas: int = 1
    discard: int | float = 0.5
    keep_trajectories: bool = False
    time_series: bool = False
    text: str = ""

    @classmethod
    def from_toml(cls, text: str, source: str = "sweep") -> SweepSpec:
        return cls.from_dict(loads_toml(text, source), text)

    @classmethod
    def load(cls, path: str | os.PathLike) -> SweepSpec:
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except OSError as err:
            raise ParameterError(f"sweep: cannot read {os.fspath(path)!r} ({err.strerror})") from None
        return cls.from_toml(text, f"sweep file {os.fspath(path)!r}")

    @classmethod
    def from_dict(cls, data: dict[str, Any], text: str = "") -> SweepSpec:
        """Validate everything, every grid point included, before any work is done."""
        _check(data, TABLES, "")
        tables = {}
        for name in TABLES:
            table = data.get(name, {})
            if not isinstance(table, dict):
                raise ParameterError(f"{name}: must be a table [{name}] (got {table!r})")
            tables[name] = table
        settings, base, grid = tables["sweep"], tables["base"], tables["grid"]
        _check(settings, tuple(SWEEP_DEFAULTS), "sweep.")
        _check(base, PARAMETER_KEYS, "base.", seed_hint=True)
        _check(grid, PARAMETER_KEYS, "grid.", seed_hint=True)
        for key in grid:
            if key in base:
                raise ParameterError(f"grid.{key}: also set in [base]; keep it in one of the two")
        values = {key: expand(key, value) for key, value in grid.items()}
        s = {**SWEEP_DEFAULTS, **settings}
        seed = integer("sweep.seed", s["seed"], 0)
        if seed >= 2**63:
            raise ParameterError(f"sweep.seed: must be a whole number in [0, 2**63) (got {seed})")
        replicas = integer("sweep.replicas", s["replicas"], 1)
        discard = s["discard"]
        if isinstance(discard, bool) or not isinstance(discard, numbers.Real):
            raise ParameterError(f"sweep.discard: must be a number of steps (integer) or a fraction "
                                 f"in [0, 1) (got {discard!r})")
        if isinstance(discard, numbers.Integral):
            discard = integer("sweep.discard", discard, 0)
        elif not 0.0 <= discard < 1.0:
            raise ParameterError(f"sweep.discard: a fraction must be in [0, 1) (got {discard!r})")
        for flag in ("keep_trajectories", "time_series"):
            if not isinstance(s[flag], bool):
                raise ParameterError(f"sweep.{flag}: must be true or false (got {s[flag]!r})")
        spec = cls(base=dict(base), grid=values, seed=seed, replicas=replicas, discard=discard,
                   keep_trajectories=s["keep_trajectories"], time_series=s["time_series"], text=text)
        spec.points()  # validates every point's configuration
        return spec

    def with_backend(self, backend: str) -> SweepSpec:
        """This sweep with every run on ``backend`` (what ``flocking sweep --backend`` does);
        the runs' identities change with it, as their results do."""
        if "backend" in self.grid:
            raise ParameterError("backend: the sweep file sweeps over backend ([grid]); leave out --backend")
        spec = dataclasses.replace(self, base={**self.base, "backend": backend})
        spec.points()  # validates every point on that backend
        return spec

    @property
    def dims(self) -> tuple[str, ...]:
        return (*self.grid, "replica")

    @property
    def shape(self) -> tuple[int, ...]:
        return (*(len(v) for v in self.grid.values()), self.replicas)

    def discard_steps(self, steps: int) -> int:
        """The number of leading steps left out of the measurement of a run of ``steps``."""
        if isinstance(self.discard, float):
            return int(math.floor(self.discard * steps))
        return self.discard

    def points(self) -> list[Point]:
        """Every run, in grid order (the last grid key and then the replica vary fastest)."""
        out = []
        ranges = [range(len(v)) for v in self.grid.values()]
        for index in itertools.product(*ranges):
            params = {key: self.grid[key][i] for key, i in zip(self.grid, index)}
            try:
                config = RunConfig.from_dict({**self.base, **params})
                if config.backend == "cuda":
                    check_supported([config.model])
            except ParameterError as err:
                raise ParameterError(f"grid point {_show(params)}: {err}") from None
            discard = self.discard_steps(config.steps)
            if discard > config.steps - 2:  # a mean and its error need two values
                raise ParameterError(f"sweep.discard: must leave at least two steps to measure "
                                     f"({discard} of steps={config.steps} at {_show(params)})")
            for replica in range(self.replicas):
                model = config.model.replace(seed=point_seed(self.seed, params, replica))
                out.append(Point(params, replica, (*index, replica),
                                 dataclasses.replace(config, model=model), discard))
        return out


def expand(key: str, value: Any) -> list:
    """The values of one grid entry: a list, or a range ``{start, stop, num[, scale]}``."""
    where = f"grid.{key}"
    if key in LIST_VALUED:
        _check_whole_values(key, value)
    if isinstance(value, dict):
        _check(value, RANGE_KEYS, where + ".")
        for part in ("start", "stop", "num"):
            if part not in value:
                raise ParameterError(f"{where}: a range needs start, stop and num (missing {part})")
        num = integer(f"{where}.num", value["num"], 1)
        start, stop = (value[p] for p in ("start", "stop"))
        for p, x in (("start", start), ("stop", stop)):
            if isinstance(x, bool) or not isinstance(x, numbers.Real):
                raise ParameterError(f"{where}.{p}: must be a number (got {x!r})")
        scale = value.get("scale", "linear")
        if scale not in ("linear", "log"):
            raise ParameterError(f"{where}.scale: must be 'linear' or 'log' (got {scale!r})")
        if scale == "log" and (start <= 0 or stop <= 0):
            raise ParameterError(f"{where}: a log range needs start and stop > 0")
        values = [_spaced(start, stop, num, i, scale) for i in range(num)]
        if key in INTEGER_KEYS:
            values = [int(round(v)) for v in values]
    elif isinstance(value, list):
        values = list(value)
    else:
        raise ParameterError(f"{where}: must be a list of values or a range {{start, stop, num}} "
                             f"(got {value!r}; a single value goes in [base])")
    if not values:
        raise ParameterError(f"{where}: must hold at least one value")
    kinds = {type(v) for v in values}
    if not kinds <= {int, float} and len(kinds) > 1:
        raise ParameterError(f"{where}: values must all be of one kind (got {values!r})")
    if kinds == {int, float}:
        values = [float(v) for v in values]
    if len({json.dumps(v) for v in values}) != len(values):
        raise ParameterError(f"{where}: values must differ (got {values!r})")
    return values


def _check_whole_values(key: str, value: Any) -> None:
    """Refuse a single list- or table-valued parameter written as a [grid] axis."""
    def whole(v: Any) -> bool:
        if key == "field" and isinstance(v, str):  # "1,0"
            return True
        if key == "coupling":
            return isinstance(v, list) and all(isinstance(row, list) for row in v)
        return isinstance(v, list)

    if not (isinstance(value, list) and all(whole(v) for v in value)):
        one, axis = {"obstacles": ("a list of obstacles", "a list of such lists"),
                     "species": ("a list of species", "a list of such lists"),
                     "coupling": ("a matrix (a list of rows)", "a list of matrices"),
                     "field": ("a direction (a list)", "a list of directions")}[key]
        raise ParameterError(f"grid.{key}: one value is {one}, so an axis is {axis} such as "
                             f"{LIST_VALUED[key]}; a single value goes in [base] (got {value!r})")


def _spaced(start: float, stop: float, num: int, i: int, scale: str) -> float:
    if num == 1:
        return float(start)
    t = i / (num - 1)
    if scale == "log":
        return float(math.exp(math.log(start) + t * (math.log(stop) - math.log(start))))
    return float(start + t * (stop - start)) if i < num - 1 else float(stop)


def _check(data: dict, allowed: tuple[str, ...], prefix: str, seed_hint: bool = False) -> None:
    if seed_hint and "seed" in data:
        raise ParameterError(f"{prefix}seed: each run's seed derives from the sweep seed; "
                             f"set seed in [sweep]")
    try:
        check_keys(data, allowed)
    except ParameterError as err:
        raise ParameterError(f"{prefix}{err}") from None


def _show(params: dict[str, Any]) -> str:
    return "{" + ", ".join(f"{k} = {v!r}" for k, v in params.items()) + "}"


__all__ = ["Point", "SweepSpec", "expand", "point_seed", "RUN_DEFAULTS"]
