"""The parameters of a flocking model: validated, frozen, and round-tripped through TOML.

A :class:`Model` holds every parameter of the model (``docs/model.md``) under the name the
user sees (the command line uses the same words). It is resolved on construction: of ``n``,
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
flocking.checks.ParameterError: noise: must be in [0, 2*pi] for angular noise (got 7.0)
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import tomllib
from typing import Any

from . import extensions as ext
from .checks import ParameterError, check_keys, comma_numbers, fail, integer, real

#: Density and box side used when too few of ``n``, ``density`` and ``box`` are given.
DEFAULT_DENSITY = 2.0
DEFAULT_BOX = 32.0

CHOICES = {
    "dim": (2, 3),
    "speeds": ("constant", "uniform"),
    "neighbours": ("metric", "topological", "voronoi"),
    "noise_type": ("angular", "vectorial"),
    "update": ("backward", "forward"),
    "noise_scale": ("radians", "unit"),
    "alignment_rule": ("polar", "nematic"),
}

#: Above this many particles a model is refused: the state alone would not fit in memory.
MAX_PARTICLES = 2_000_000_000

#: Largest vectorial noise amplitude. Beyond about 10 the noise term already swamps every
#: sum of headings; the bound keeps ``eta * n_i`` far from overflowing.
MAX_VECTORIAL_NOISE = 1000.0


def _choice(name: str, value: Any) -> Any:
    if value not in CHOICES[name]:
        fail(name, "one of " + ", ".join(repr(c) for c in CHOICES[name]), value)
    return value


def _speed(name: str, value: Any) -> float:
    return real(name, value, low=0.0, low_open=True,
                 allowed=None if name == "speed" else "speeds that are finite numbers > 0")


def _noise(name: str, value: Any, noise_type: str, scale: str, where: str = "") -> float:
    """A noise amplitude in the model's stored form (radians for angular noise)."""
    suffix = f" ({where})" if where else ""
    if scale == "unit":
        value = real(name, value, low=0.0, high=1.0, allowed=f"in [0, 1]{suffix}")
        if noise_type == "angular":
            value = 2.0 * math.pi * value
    if noise_type == "angular":
        return real(name, value, low=0.0, high=2.0 * math.pi, allowed=f"in [0, 2*pi] for angular noise{suffix}")
    return real(name, value, low=0.0, high=MAX_VECTORIAL_NOISE,
                 allowed=f"in [0, {MAX_VECTORIAL_NOISE:g}] for vectorial noise{suffix}")


def _field_strength(name: str, value: Any, where: str = "") -> float:
    suffix = f" ({where})" if where else ""
    return real(name, value, low=0.0, high=MAX_VECTORIAL_NOISE,
                 allowed=f"in [0, {MAX_VECTORIAL_NOISE:g}]{suffix}")


def parse_box(value: Any, dim: int) -> tuple[float, ...] | None:
    """A box from a number, a sequence, or a string such as ``"4,5"``; one length per axis."""
    if value is None:
        return None
    value = comma_numbers("box", value, "a positive number or one per axis such as 4,5")
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        value = [value]
    try:
        lengths = [real("box", x, low=0.0, low_open=True) for x in value]
    except TypeError:
        fail("box", "a positive number or one per axis such as 4,5", value)
    if len(lengths) == 1:
        lengths = lengths * dim
    if len(lengths) != dim:
        fail("box", f"one number or {dim} numbers for dim={dim}", value)
    return tuple(lengths)


@dataclasses.dataclass(frozen=True)
class Model:
    """Every parameter of a flocking model (see ``docs/model.md``), validated.

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
    boundary: Any = "periodic"
    obstacles: Any = ()
    species: Any = ()
    coupling: Any = None
    vision: float = math.pi
    alignment_rule: str = "polar"
    chirality: float = 0.0
    field: Any = None
    field_strength: float = 0.0
    cohesion: float = 0.0
    cohesion_radii: Any = None
    noise_scale: dataclasses.InitVar[str] = "radians"

    def __post_init__(self, noise_scale: str) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        dim = integer("dim", self.dim, 2)
        put("dim", _choice("dim", dim))
        for name in ("speeds", "neighbours", "noise_type", "update", "alignment_rule"):
            _choice(name, getattr(self, name))
        _choice("noise_scale", noise_scale)
        put("speed", _speed("speed", self.speed))
        put("radius", real("radius", self.radius, low=0.0, low_open=True, high=1e150))  # R^2 must be finite
        put("k", integer("k", self.k, 1))
        put("alignment", real("alignment", self.alignment, low=0.0, high=1.0))
        put("delay", integer("delay", self.delay, 0))
        put("dt", real("dt", self.dt, low=0.0, low_open=True))
        put("seed", integer("seed", self.seed, 0))
        if self.seed >= 2**63:
            fail("seed", "a whole number in [0, 2**63)", self.seed)
        put("noise", _noise("noise", self.noise, self.noise_type, noise_scale))
        self._parse_extensions(noise_scale)
        self._resolve_size()
        if self.species:
            counts = ext.species_counts(self.species, self.n)
            put("species", tuple(dataclasses.replace(s, n=c) for s, c in zip(self.species, counts)))
        self._check_step_length()
        ext.check_obstacles(self.obstacles, self.box, self.walls, self.max_speed * self.dt)

    def _parse_extensions(self, noise_scale: str) -> None:
        """Walls, obstacles, species, coupling, vision, chirality and field (docs/model.md's
        extensions), each checked on its own; checks against the box follow its resolution."""
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        dim = self.dim
        put("boundary", ext.parse_boundary(self.boundary, dim))
        put("obstacles", ext.parse_obstacles(self.obstacles, dim))
        species = ext.parse_species(self.species, dim)
        checked = []
        for sp in species:
            where = f"species {sp.name!r}"
            values = {}
            if sp.speed is not None:
                values["speed"] = _speed(f"species: {where} speed", sp.speed)
            if sp.speeds is not None and sp.speeds not in CHOICES["speeds"]:
                fail("species", f"speeds one of 'constant', 'uniform' ({where})", sp.speeds)
            if sp.noise is not None:
                values["noise"] = _noise("species", sp.noise, self.noise_type, noise_scale, where)
            if sp.alignment is not None:
                values["alignment"] = real("species", sp.alignment, low=0.0, high=1.0,
                                            allowed=f"alignment in [0, 1] ({where})")
            if sp.chirality is not None:
                values["chirality"] = self._chirality("species", sp.chirality, where)
            if sp.field_strength is not None:
                values["field_strength"] = _field_strength("species", sp.field_strength, where)
            checked.append(dataclasses.replace(sp, **values))
        put("species", tuple(checked))
        if checked and checked[0].n is not None and self.n is None and (self.density is None or self.box is None):
            put("n", sum(ext.species_counts(self.species, None)))  # counts given: they make n
        put("coupling", ext.parse_coupling(self.coupling, max(len(checked), 1)))
        put("vision", real("vision", self.vision, low=0.0, low_open=True, high=math.pi,
                            allowed="a half-angle in (0, pi]"))
        put("chirality", self._chirality("chirality", self.chirality))
        put("field", ext.parse_field(self.field, dim))
        put("field_strength", _field_strength("field_strength", self.field_strength))
        put("cohesion", real("cohesion", self.cohesion, low=0.0, high=ext.MAX_WEIGHT))
        if self.cohesion or self.cohesion_radii is not None:
            put("cohesion_radii", ext.parse_cohesion_radii(self.cohesion_radii, self.radius))
        if self.field is None and any(h > 0 for h in self.species_values("field_strength")):
            raise ParameterError("field: must be given (a direction such as 1,0) when a field_strength is above 0")

    def _chirality(self, name: str, value: Any, where: str = "") -> float:
        omega = real(name, value, allowed=f"a finite number{f' ({where})' if where else ''}")
        if omega != 0.0 and self.dim == 3:
            fail(name, f"0 in 3D: chirality is a turn in the plane{f' ({where})' if where else ''}", omega)
        if not abs(omega) * self.dt <= math.pi:
            fail(name, f"at most pi / dt = {math.pi / self.dt:.6g} in magnitude: a turn of at most half a "
                        f"circle a step{f' ({where})' if where else ''}", omega)
        return omega

    def _check_step_length(self) -> None:
        """A step moves a particle at most ``max_speed * dt``: it must be finite and at most
        the smallest periodic box side (a longer step would wrap around the box more than
        once, and an overflowing one would leave the box altogether), and below half of
        every side bounded by walls."""
        step, name = self.max_speed * self.dt, "speed" if not self.species else "species"
        for length, wall in zip(self.box, self.walls):
            limit, words = (length / 2, "half of each side with walls") if wall else (length, "the smallest box side")
            if not (step < limit if wall else step <= limit):  # also refuses an overflow to inf
                allowed = (f"{'below' if wall else 'at most'} {limit / self.dt:.6g} with dt = {self.dt:g}, so that "
                           f"one step (speed * dt) covers {'less than' if wall else 'at most'} {words}, {limit:.6g}")
                fail(name, allowed, self.max_speed)

    def _resolve_size(self) -> None:
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        n, density = self.n, self.density
        box = parse_box(self.box, self.dim)
        if n is not None:
            n = integer("n", n, 1)
        if density is not None:
            density = real("density", density, low=0.0, low_open=True)
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
            fail("box", "sides whose product (the volume) is a finite number above 0", box)
        if n is None:
            if not density * volume <= MAX_PARTICLES:  # n = density * volume, within bounds
                if self.density is None:
                    fail("box", f"small enough for at most {MAX_PARTICLES:.0e} particles at density {density:g}",
                          box)
                fail("density", f"at most {MAX_PARTICLES:.0e} particles in a box of volume {volume:g}", density)
            n = round(density * volume)
            if n < 1:
                fail("density", f"large enough for at least one particle in a box of volume {volume:g}",
                      density)
        if n > MAX_PARTICLES:
            fail("n", f"at most {MAX_PARTICLES:.0e}", n)
        put("n", n)
        put("box", box)
        put("density", n / volume)

    # -- the extensions, resolved --------------------------------------------------------

    @property
    def walls(self) -> tuple[bool, ...]:
        """Per axis, whether it is bounded by walls."""
        return tuple(b == "wall" for b in self.boundary)

    @property
    def species_counts(self) -> tuple[int, ...]:
        """Particles of each species (one species, all of them, when none are given);
        species ``s`` holds the ids from the sum of the earlier counts on."""
        return tuple(sp.n for sp in self.species) if self.species else (self.n,)

    @property
    def species_names(self) -> tuple[str, ...]:
        return tuple(sp.name for sp in self.species) if self.species else ("A",)

    def species_values(self, name: str) -> tuple[Any, ...]:
        """One parameter (``speed``, ``speeds``, ``noise``, ``alignment``, ``chirality``,
        ``field_strength``) for each species: its own value, or the global one.

        >>> Model(n=10, box=5, species=[{"n": 4}, {"n": 6, "noise": 2.0}]).species_values("noise")
        (1.0, 2.0)
        """
        if not self.species:
            return (getattr(self, name),)
        return tuple(getattr(self, name) if getattr(sp, name) is None else getattr(sp, name) for sp in self.species)

    @property
    def field_direction(self) -> tuple[float, ...] | None:
        """The field's unit direction ``g`` (``field`` holds the direction as given),
        normalised without overflow or underflow for any finite, non-zero length.

        >>> Model(n=10, box=4.0, field=(1e-170, 1e-170)).field_direction
        (0.7071067811865475, 0.7071067811865475)
        """
        if self.field is None:
            return None
        return ext.unit_vector(self.field)

    @property
    def max_speed(self) -> float:
        return max(self.species_values("speed"))

    @property
    def extended(self) -> bool:
        """Whether any extension beyond the plain model is on (a single species that changes
        only the speeds is not one: the plain step takes a speed per particle)."""
        return bool(self.extensions)

    @property
    def extensions(self) -> tuple[str, ...]:
        """The names of the extensions that are on, in the order of the model description.

        >>> Model(n=100, box=10.0, vision=2.0, chirality=0.1).extensions
        ('vision', 'chirality')
        >>> Model(n=100, box=10.0, species=[{"fraction": 1.0, "speeds": "uniform"}]).extensions
        ()
        """
        species = len(self.species) > 1 or any(
            getattr(sp, name) is not None for sp in self.species for name in ("noise", "alignment"))
        on = {"walls": any(self.walls), "obstacles": bool(self.obstacles), "species": species,
              "coupling": self.coupling is not None, "vision": self.vision != math.pi,
              "nematic alignment": self.alignment_rule == "nematic", "cohesion": self.cohesion > 0.0,
              "chirality": any(self.species_values("chirality")), "field": any(self.species_values("field_strength"))}
        return tuple(name for name, value in on.items() if value)

    # -- conversions -------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Every parameter, resolved (``n`` and ``box``; ``density`` follows from them).
        The extensions appear only where they differ from the plain model."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in EXTENSION_DEFAULTS}
        del d["density"]
        d["box"] = list(self.box)
        for name, default in EXTENSION_DEFAULTS.items():
            value = getattr(self, name)
            if name == "boundary":
                value = value[0] if len(set(value)) == 1 else ",".join(value)
            if value != default and value is not None:
                d[name] = value
        if self.obstacles:
            d["obstacles"] = [o.to_dict() for o in self.obstacles]
        if self.species:
            d["species"] = [sp.to_dict() for sp in self.species]
        if self.coupling is not None:
            d["coupling"] = [list(row) for row in self.coupling]
        if self.field is not None:
            d["field"] = list(self.field)
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
        reach = {"metric": f" (R={self.radius:g})", "topological": f" (k={self.k})"}.get(self.neighbours, "")
        text += f"{self.neighbours}{reach}, "
        text += f"{self.noise_type} noise {self.noise:.4g}, v0={self.speed:g}"
        if self.alignment != 1.0:
            text += f", alignment={self.alignment:g}"
        if self.delay:
            text += f", delay={self.delay}"
        if any(self.walls):
            text += f", walls {'all' if all(self.walls) else 'on ' + ''.join('xyz'[a] for a, w in enumerate(self.walls) if w)}"
        if self.obstacles:
            text += f", {len(self.obstacles)} obstacle{'s' * (len(self.obstacles) > 1)}"
        if self.species:
            text += ", species " + "+".join(f"{sp.name}:{sp.n}" for sp in self.species)
        if self.coupling is not None:
            text += ", coupling " + str([list(r) for r in self.coupling]).replace(" ", "")
        if self.vision != math.pi:
            text += f", vision {self.vision:.4g}"
        if self.alignment_rule != "polar":
            text += f", {self.alignment_rule}"
        if self.chirality:
            text += f", chirality {self.chirality:g}"
        if self.cohesion:
            text += f", cohesion {self.cohesion:g} (r_c, r_e, r_a = {', '.join(f'{r:g}' for r in self.cohesion_radii)})"
        if self.field_strength or any(self.species_values("field_strength")):
            text += f", field {tuple(round(g, 4) for g in self.field_direction)} strength {self.field_strength:g}"
        return text


MODEL_KEYS = tuple(f.name for f in dataclasses.fields(Model)) + ("noise_scale",)

#: The extensions' parameters and their values when off (as :meth:`Model.to_dict` writes them).
EXTENSION_DEFAULTS = {"boundary": "periodic", "obstacles": (), "species": (), "coupling": None,
                      "vision": math.pi, "alignment_rule": "polar", "chirality": 0.0, "field": None,
                      "field_strength": 0.0, "cohesion": 0.0, "cohesion_radii": None}


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
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items() if v is not None) + "}"
    raise TypeError(f"cannot write {value!r} to TOML")


def _toml_key(key: str) -> str:
    return key if key.replace("_", "").replace("-", "").isalnum() and key.isascii() else _toml_value(key)


def dumps_toml(data: dict[str, Any]) -> str:
    """A mapping of scalars, lists and tables (written inline) as TOML (``None`` values
    are left out).

    >>> print(dumps_toml({"n": 3, "box": [4.0, 5.0], "obstacles": [{"centre": [1.0, 2.0], "radius": 0.5}]}), end="")
    n = 3
    box = [4.0, 5.0]
    obstacles = [{centre = [1.0, 2.0], radius = 0.5}]
    """
    return "".join(f"{k} = {_toml_value(v)}\n" for k, v in data.items() if v is not None)


def loads_toml(text: str, source: str = "config") -> dict[str, Any]:
    """Parse TOML, turning syntax errors into one-line :class:`ParameterError`."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ParameterError(f"{source}: not valid TOML ({err})") from None

