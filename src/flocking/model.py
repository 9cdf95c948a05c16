"""The parameters of a flocking model: validated, frozen, and round-tripped through TOML.

A :class:`Model` holds every parameter of ``shared/MODEL.md`` under the name the user
sees (the command line uses the same words). It is resolved on construction: of ``n``,
``density`` and ``box`` at most two may be given, and the rest is derived, so a model
always knows its particle count and its box.

>>> m = Model(n=1000, density=2.0, noise=1.0)
>>> m.n, m.box
(1000, (22.360679774997898, 22.360679774997898))
>>> Model.from_dict(m.to_dict()) == m
True
>>> Model(noise=7.0)
Traceback (most recent call last):
...
flocking.model.ParameterError: noise: must be in [0, 2*pi] for angular noise (got 7.0)
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import tomllib
from typing import Any

#: Density and box side used when too few of ``n``, ``density`` and ``box`` are given.
DEFAULT_DENSITY = 2.0
DEFAULT_BOX = 32.0

CHOICES = {
    "dim": (2, 3),
    "speeds": ("constant", "uniform"),
    "neighbours": ("metric", "topological"),
    "noise_type": ("angular", "vectorial"),
    "update": ("backward", "forward"),
    "noise_scale": ("radians", "unit"),
}

#: Above this many particles a model is refused: the state alone would not fit in memory.
MAX_PARTICLES = 2_000_000_000

#: Largest vectorial noise amplitude. Beyond about 10 the noise term already swamps every
#: sum of headings; the bound keeps ``eta * n_i`` far from overflowing.
MAX_VECTORIAL_NOISE = 1000.0


class ParameterError(ValueError):
    """An invalid parameter; the message names the parameter and what is allowed."""


def _fail(name: str, allowed: str, value: Any) -> None:
    raise ParameterError(f"{name}: must be {allowed} (got {value!r})")


def _real(name: str, value: Any, *, low: float | None = None, high: float | None = None,
          low_open: bool = False, allowed: str | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        _fail(name, "a number", value)
    value = float(value)
    ok = math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        if allowed is None:
            if high is None:
                allowed = f"a finite number {'>' if low_open else '>='} {low:g}"
            else:
                allowed = f"in {'(' if low_open else '['}{low:g}, {high:g}]"
        _fail(name, allowed, value)
    return value


def _integer(name: str, value: Any, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            _fail(name, f"a whole number >= {low}", value)
    if value < low:
        _fail(name, f"a whole number >= {low}", value)
    return int(value)


def _choice(name: str, value: Any) -> Any:
    if value not in CHOICES[name]:
        _fail(name, "one of " + ", ".join(repr(c) for c in CHOICES[name]), value)
    return value


def parse_box(value: Any, dim: int) -> tuple[float, ...] | None:
    """A box from a number, a sequence, or a string such as ``"4,5"``; one length per axis."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            value = [float(x) for x in value.split(",")]
        except ValueError:
            _fail("box", "a positive number or one per axis such as 4,5", value)
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        value = [value]
    try:
        lengths = [_real("box", x, low=0.0, low_open=True) for x in value]
    except TypeError:
        _fail("box", "a positive number or one per axis such as 4,5", value)
    if len(lengths) == 1:
        lengths = lengths * dim
    if len(lengths) != dim:
        _fail("box", f"one number or {dim} numbers for dim={dim}", value)
    return tuple(lengths)


@dataclasses.dataclass(frozen=True)
class Model:
    """Every parameter of a flocking model (see ``shared/MODEL.md``), validated.

    ``noise`` is always stored as the radian amplitude ``eta`` (angular noise in
    ``[0, 2 pi]``) or the vectorial amplitude; give ``noise_scale="unit"`` to pass the
    ``eta'`` in ``[0, 1]`` that many papers use (``eta = 2 pi eta'`` for angular noise;
    vectorial amplitudes are already on that scale and are kept as given).
    """

    dim: int = 2
    n: int | None = None
    density: float | None = None
    box: Any = None
    speed: float = 0.5
    speeds: str = "constant"
    neighbours: str = "metric"
    radius: float = 1.0
    k: int = 7
    noise: float = 1.0
    noise_type: str = "angular"
    alignment: float = 1.0
    delay: int = 0
    dt: float = 1.0
    update: str = "backward"
    seed: int = 0
    noise_scale: dataclasses.InitVar[str] = "radians"

    def __post_init__(self, noise_scale: str) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        dim = _integer("dim", self.dim, 2)
        put("dim", _choice("dim", dim))
        for name in ("speeds", "neighbours", "noise_type", "update"):
            _choice(name, getattr(self, name))
        _choice("noise_scale", noise_scale)
        put("speed", _real("speed", self.speed, low=0.0, low_open=True))
        put("radius", _real("radius", self.radius, low=0.0, low_open=True, high=1e150))  # R^2 must be finite
        put("k", _integer("k", self.k, 1))
        put("alignment", _real("alignment", self.alignment, low=0.0, high=1.0))
        put("delay", _integer("delay", self.delay, 0))
        put("dt", _real("dt", self.dt, low=0.0, low_open=True))
        put("seed", _integer("seed", self.seed, 0))
        if self.seed >= 2**63:
            _fail("seed", "a whole number in [0, 2**63)", self.seed)
        noise = self.noise
        if noise_scale == "unit":
            noise = _real("noise", noise, low=0.0, high=1.0)
            if self.noise_type == "angular":
                noise = 2.0 * math.pi * noise
        if self.noise_type == "angular":
            noise = _real("noise", noise, low=0.0, high=2.0 * math.pi,
                          allowed="in [0, 2*pi] for angular noise")
        else:
            noise = _real("noise", noise, low=0.0, high=MAX_VECTORIAL_NOISE,
                          allowed=f"in [0, {MAX_VECTORIAL_NOISE:g}] for vectorial noise")
        put("noise", noise)
        self._resolve_size()
        self._check_step_length()

    def _check_step_length(self) -> None:
        """A step moves a particle at most ``speed * dt``: it must be finite and at most the
        smallest box side (a longer step would wrap around the box more than once, and an
        overflowing one would leave the box altogether)."""
        side = min(self.box)
        if not self.speed * self.dt <= side:  # also refuses an overflow to inf
            _fail("speed", f"at most {side / self.dt:.6g} with dt = {self.dt:g}, so that one step "
                  f"(speed * dt) covers at most the smallest box side, {side:.6g}", self.speed)

    def _resolve_size(self) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        n, density = self.n, self.density
        box = parse_box(self.box, self.dim)
        if n is not None:
            n = _integer("n", n, 1)
        if density is not None:
            density = _real("density", density, low=0.0, low_open=True)
        if n is not None and density is not None and box is not None:
            raise ParameterError("n, density, box: give at most two of them (the third follows)")
        if density is None and (n is None or box is None):
            density = DEFAULT_DENSITY
        if box is None:
            if n is None:
                box = (DEFAULT_BOX,) * self.dim
            else:
                box = ((n / density) ** (1.0 / self.dim),) * self.dim
        volume = math.prod(box)
        if not (math.isfinite(volume) and volume > 0):
            _fail("box", "sides whose product (the volume) is a finite number above 0", box)
        if n is None:
            if not density * volume <= MAX_PARTICLES:  # n = density * volume, within bounds
                if self.density is None:
                    _fail("box", f"small enough for at most {MAX_PARTICLES:.0e} particles at density {density:g}",
                          box)
                _fail("density", f"at most {MAX_PARTICLES:.0e} particles in a box of volume {volume:g}", density)
            n = round(density * volume)
            if n < 1:
                _fail("density", f"large enough for at least one particle in a box of volume {volume:g}",
                      density)
        if n > MAX_PARTICLES:
            _fail("n", f"at most {MAX_PARTICLES:.0e}", n)
        put("n", n)
        put("box", box)
        put("density", n / volume)

    # -- conversions -------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Every parameter, resolved (``n`` and ``box``; ``density`` follows from them)."""
        d = dataclasses.asdict(self)
        del d["density"]
        d["box"] = list(self.box)
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Model:
        """Build a model from a mapping, refusing unknown keys with a suggestion."""
        check_keys(data, MODEL_KEYS)
        return cls(**data)

    def replace(self, **changes: Any) -> Model:
        """A copy with some parameters changed; sizes are re-resolved from what is given.

        >>> Model(n=100, box=10).replace(noise=2.0).n
        100
        """
        data = self.to_dict()
        if {"n", "density", "box"} & changes.keys():
            for key in ("n", "box"):
                data.pop(key)
        data.update(changes)
        return Model(**data)

    @property
    def volume(self) -> float:
        return math.prod(self.box)

    def __str__(self) -> str:
        text = f"{self.dim}D, N={self.n}, box={'x'.join(f'{x:g}' for x in self.box)}, "
        text += f"{self.neighbours} ({f'R={self.radius:g}' if self.neighbours == 'metric' else f'k={self.k}'}), "
        text += f"{self.noise_type} noise {self.noise:.4g}, v0={self.speed:g}"
        if self.alignment != 1.0:
            text += f", alignment={self.alignment:g}"
        if self.delay:
            text += f", delay={self.delay}"
        return text


MODEL_KEYS = tuple(f.name for f in dataclasses.fields(Model)) + ("noise_scale",)


def check_keys(data: dict[str, Any], allowed: tuple[str, ...]) -> None:
    """Refuse unknown keys, naming the key and the closest allowed one."""
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            name = key if str(key).isidentifier() else repr(key)  # keep the message on one line
            raise ParameterError(f"{name}: unknown parameter{hint}")


# -- TOML ------------------------------------------------------------------------------


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        return repr(float(value))  # repr round-trips every double exactly
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def dumps_toml(data: dict[str, Any]) -> str:
    """A flat mapping of scalars and lists as TOML (``None`` values are left out).

    >>> print(dumps_toml({"n": 3, "box": [4.0, 5.0], "update": "forward"}), end="")
    n = 3
    box = [4.0, 5.0]
    update = "forward"
    """
    return "".join(f"{k} = {_toml_value(v)}\n" for k, v in data.items() if v is not None)


def loads_toml(text: str, source: str = "config") -> dict[str, Any]:
    """Parse TOML, turning syntax errors into one-line :class:`ParameterError`."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ParameterError(f"{source}: not valid TOML ({err})") from None
