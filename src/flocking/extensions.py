"""The parameters beyond the plain Vicsek model: walls, obstacles, species, coupling.

:class:`~flocking.model.Model` holds them; this module parses what a user writes (Python
values or TOML) into frozen values and checks each against the rest of the model. Every
check raises a one-line :class:`~flocking.checks.ParameterError` naming the parameter.

>>> parse_boundary("periodic,wall", 2)
('periodic', 'wall')
>>> parse_obstacles([{"centre": [5, 5], "radius": 2}], 2)
(Obstacle(centre=(5.0, 5.0), radius=2.0),)
>>> parse_obstacles([{"center": [5, 5], "radius": 2}], 2)
Traceback (most recent call last):
...
flocking.checks.ParameterError: obstacles: unknown key 'center'; did you mean 'centre'? (allowed: centre, radius)
>>> species_counts(parse_species([{"fraction": 0.3}, {"fraction": 0.7}], 2), 10)
(3, 7)
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
from typing import Any

from .checks import ParameterError, comma_numbers, fail, real
from .rules.geometry import minimum_image, reach

BOUNDARIES = ("periodic", "wall")

#: Keys a species may set; every one but ``name``, ``n`` and ``fraction`` replaces the
#: global value of that parameter for the species' particles.
SPECIES_KEYS = ("name", "n", "fraction", "speed", "speeds", "noise", "alignment", "chirality", "field_strength")
#: Per-species parameters, in the order of :meth:`flocking.model.Model.species_table`.
PER_SPECIES = ("speed", "noise", "alignment", "chirality", "field_strength")

#: Largest magnitude of a coupling, field strength (like the vectorial noise, far beyond
#: where it already dominates every sum, and far from overflowing ``h * n_i``).
MAX_WEIGHT = 1000.0


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A fixed disc (2D) or sphere (3D) that particles bounce off."""

    centre: tuple[float, ...]
    radius: float

    def to_dict(self) -> dict[str, Any]:
        return {"centre": list(self.centre), "radius": self.radius}


@dataclasses.dataclass(frozen=True)
class Species:
    """One species: its particle count (or the fraction it was given as) and the
    parameters it overrides (``None``: the global value)."""

    name: str
    n: int | None = None
    fraction: float | None = None
    speed: float | None = None
    speeds: str | None = None
    noise: float | None = None
    alignment: float | None = None
    chirality: float | None = None
    field_strength: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """What the user gave: the fraction if it was given as one, else the count."""
        d = {k: v for k, v in dataclasses.asdict(self).items() if v is not None}
        if self.fraction is not None:
            d.pop("n", None)
        return d


def _mapping(name: str, value: Any, allowed: tuple[str, ...], where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        fail(name, f"a list of tables such as {where}", value)
    for key in value:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ParameterError(f"{name}: unknown key {key!r}{hint} (allowed: {', '.join(allowed)})")
    return value


def _sequence(name: str, value: Any, example: str) -> list:
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
        fail(name, f"a list such as {example}", value)
    return list(value)


def parse_boundary(value: Any, dim: int) -> tuple[str, ...]:
    """One of :data:`BOUNDARIES` per axis, from one word, ``"periodic,wall"`` or a list."""
    words = value.split(",") if isinstance(value, str) else value
    try:
        words = [w.strip() if isinstance(w, str) else w for w in words]
    except TypeError:
        fail("boundary", "'periodic', 'wall' or one per axis such as periodic,wall", value)
    if len(words) == 1:
        words = words * dim
    if len(words) != dim or any(w not in BOUNDARIES for w in words):
        fail("boundary", f"'periodic', 'wall' or {dim} of them separated by commas", value)
    return tuple(words)


def parse_obstacles(value: Any, dim: int) -> tuple[Obstacle, ...]:
    """Obstacles from a list of ``{centre = [...], radius = a}`` (or of :class:`Obstacle`)."""
    example = "[{centre = [16, 16], radius = 4}]"
    obstacles = []
    for i, item in enumerate(_sequence("obstacles", value, example)):
        if isinstance(item, Obstacle):
            item = item.to_dict()
        item = _mapping("obstacles", item, ("centre", "radius"), example)
        if "centre" not in item or "radius" not in item:
            raise ParameterError(f"obstacles: obstacle {i} needs a centre and a radius (got {item!r})")
        centre = item["centre"]
        if isinstance(centre, (str, bytes)) or not hasattr(centre, "__len__") or len(centre) != dim:
            fail("obstacles", f"centres of {dim} numbers", centre)
        centre = tuple(real("obstacles", x) for x in centre)
        radius = real("obstacles", item["radius"], low=0.0, low_open=True,
                      allowed="radii that are finite numbers > 0")
        obstacles.append(Obstacle(centre, radius))
    return tuple(obstacles)


def parse_species(value: Any, dim: int) -> tuple[Species, ...]:
    """Species from a list of tables; values are checked here, counts in :func:`species_counts`."""
    example = "[{fraction = 0.8}, {fraction = 0.2, noise = 2.0}]"
    items = _sequence("species", value, example)
    if not items:
        return ()
    species = []
    for i, item in enumerate(items):
        if isinstance(item, Species):
            item = item.to_dict()
        item = dict(_mapping("species", item, SPECIES_KEYS, example))
        name = item.pop("name", "ABCDEFGHIJKLMNOPQRSTUVWXYZ"[i] if i < 26 else f"S{i}")
        if not isinstance(name, str) or not name or len(name) > 32 or not name.isprintable():
            fail("species", "names of 1 to 32 printable characters", name)
        species.append(Species(name=name, **item))
    names = [s.name for s in species]
    if len(set(names)) != len(names):
        fail("species", "distinct names", names)
    given = {("n" if s.n is not None else "") + ("fraction" if s.fraction is not None else "") for s in species}
    if given not in ({"n"}, {"fraction"}):
        raise ParameterError("species: give every species either n or fraction, the same for all "
                             f"(got {[s.to_dict() for s in species]!r})"[:300])
    return tuple(species)


def species_counts(species: tuple[Species, ...], n: int | None) -> tuple[int, ...]:
    """Particle counts of the species, adding up to ``n`` (when given).

    Fractions must add up to 1; they round by largest remainder, ties to the first species.
    """
    if species[0].n is not None:
        counts = []
        for s in species:
            if isinstance(s.n, bool) or not isinstance(s.n, numbers.Integral) or s.n < 0:
                fail("species", "counts n that are whole numbers >= 0", s.n)
            counts.append(int(s.n))
        if n is not None and sum(counts) != n:
            raise ParameterError(f"species: the counts must add up to n = {n} (got {sum(counts)})")
        _refuse_empty(species, counts)
        return tuple(counts)
    fractions = [real("species", s.fraction, low=0.0, high=1.0, allowed="fractions in [0, 1]") for s in species]
    if not math.isclose(sum(fractions), 1.0, rel_tol=0, abs_tol=1e-9):
        raise ParameterError(f"species: the fractions must add up to 1 (got {sum(fractions):.12g})")
    exact = [f * n for f in fractions]
    counts = [math.floor(x) for x in exact]
    order = sorted(range(len(exact)), key=lambda i: (-(exact[i] - counts[i]), i))
    for i in order[: n - sum(counts)]:
        counts[i] += 1
    _refuse_empty(species, counts)
    return tuple(counts)


def _refuse_empty(species: tuple[Species, ...], counts: list[int]) -> None:
    """An empty species has no polar order and no say in the flock: it is refused."""
    for s, count in zip(species, counts):
        if count < 1:
            given = f"n = {s.n}" if s.fraction is None else f"fraction {s.fraction:g} of n = {sum(counts)}"
            raise ParameterError(f"species: every species must hold at least one particle "
                                 f"(species {s.name!r} has {given}, 0 particles)")


def parse_coupling(value: Any, count: int) -> tuple[tuple[float, ...], ...] | None:
    """A ``count x count`` matrix of weights in ``[-MAX_WEIGHT, MAX_WEIGHT]``; ``None`` if
    absent or all 1 (the plain sum)."""
    if value is None:
        return None
    example = "[[1, -1], [-1, 1]]"
    rows = _sequence("coupling", value, example)
    if len(rows) != count or any(isinstance(r, (str, bytes)) or not hasattr(r, "__len__") or len(r) != count
                                 for r in rows):
        fail("coupling", f"a {count} x {count} matrix, one row and column per species, such as {example}", value)
    allowed = f"weights in [-{MAX_WEIGHT:g}, {MAX_WEIGHT:g}]"
    matrix = tuple(tuple(real("coupling", x, low=-MAX_WEIGHT, high=MAX_WEIGHT, allowed=allowed) for x in row)
                   for row in rows)
    return None if all(x == 1.0 for row in matrix for x in row) else matrix


def parse_field(value: Any, dim: int) -> tuple[float, ...] | None:
    """The field's direction as given (any finite, non-zero length); from a list or ``"1,0"``.

    >>> parse_field("1e-300,-1e-300", 2)
    (1e-300, -1e-300)
    """
    if value is None:
        return None
    value = comma_numbers("field", value, f"a direction of {dim} numbers such as 1,0")
    items = _sequence("field", value, "[1, 0]")
    if len(items) != dim:
        fail("field", f"a direction of {dim} numbers", value)
    g = tuple(real("field", x, allowed="a direction of finite numbers") for x in items)
    if not any(g):
        fail("field", "a direction: a non-zero vector", value)
    return g


#: The default radii ``(r_c, r_e, r_a)`` of cohesion, in units of the interaction radius
#: ``R``: Gregoire and Chate's 0.2, 0.5 and 0.8 (PRL 92, 025702, 2004).
COHESION_RADII = (0.2, 0.5, 0.8)


def parse_cohesion_radii(value: Any, radius: float) -> tuple[float, float, float]:
    """The radii ``(r_c, r_e, r_a)`` of cohesion: the hard core, the distance of
    equilibrium and the start of full attraction, with ``0 <= r_c < r_e < r_a``; from a
    list or ``"0.2,0.5,0.8"``, or (``None``) :data:`COHESION_RADII` times ``radius``.

    >>> parse_cohesion_radii(None, 2.0)
    (0.4, 1.0, 1.6)
    """
    if value is None:
        return tuple(f * radius for f in COHESION_RADII)
    allowed = "three lengths r_c, r_e, r_a with 0 <= r_c < r_e < r_a, such as 0.2,0.5,0.8"
    value = comma_numbers("cohesion_radii", value, allowed)
    items = _sequence("cohesion_radii", value, "[0.2, 0.5, 0.8]")
    if len(items) != 3:
        fail("cohesion_radii", allowed, value)
    rc, re, ra = (real("cohesion_radii", x, low=0.0, allowed=allowed) for x in items)
    if not (rc < re < ra):
        fail("cohesion_radii", allowed, value)
    return rc, re, ra


def unit_vector(v: tuple[float, ...]) -> tuple[float, ...]:
    """``v / |v|`` for any finite, non-zero ``v``, without overflow or underflow: the
    components are first divided by the largest magnitude (exact for a power of two,
    and the largest becomes +-1), so the sum of squares lies in ``[1, d]``.

    >>> unit_vector((3e300, -4e300))
    (0.6, -0.8)
    >>> unit_vector((1e-320, 0.0))
    (1.0, 0.0)
    """
    scale = max(abs(x) for x in v)
    if not (math.isfinite(scale) and scale > 0.0):
        raise ValueError(f"unit_vector: needs a finite, non-zero vector (got {v!r})")
    w = tuple(x / scale for x in v)
    norm = math.sqrt(sum(x * x for x in w))
    return tuple(x / norm for x in w)


def periodic_distance(a: tuple[float, ...], b: tuple[float, ...], box: tuple[float, ...],
                      walls: tuple[bool, ...]) -> float:
    """Distance between two points in the box, with the minimum image on periodic axes
    (:func:`flocking.rules.geometry.minimum_image`).

    >>> periodic_distance((1.0, 1.0), (9.0, 9.0), (10.0, 10.0), (False, True))
    8.246211251235321
    """
    total = 0.0
    for x, y, length, wall in zip(a, b, box, walls):
        dx = minimum_image(x - y, length, reach(length, wall))
        total += dx * dx
    return math.sqrt(total)


def check_obstacles(obstacles: tuple[Obstacle, ...], box: tuple[float, ...], walls: tuple[bool, ...],
                    step: float) -> None:
    """Obstacles inside the box, each wider than a step, at least a step from every wall,
    from each other and from their own periodic images (``L - 2a >= step`` along each
    periodic axis). A particle inside an obstacle got there within one step, so its
    mirror point lies less than a step outside the surface: these guarantee that it lands
    outside every obstacle (and every image) and inside the walls."""
    for i, ob in enumerate(obstacles):
        if not ob.radius > step:
            fail("obstacles", f"radii above one step, speed * dt = {step:.6g} (obstacle {i})", ob.radius)
        for a, (c, length, wall) in enumerate(zip(ob.centre, box, walls)):
            if not 0.0 <= c <= length:
                fail("obstacles", f"centres inside the box (obstacle {i}, axis {a}: [0, {length:g}])", c)
            if wall and not (c - ob.radius >= step and c + ob.radius <= length - step):
                raise ParameterError(f"obstacles: obstacle {i} must keep at least one step ({step:.6g}) from the "
                                     f"walls of axis {a} (centre {c:g}, radius {ob.radius:g}, box {length:g})")
            if not wall and not length - 2 * ob.radius >= step:
                raise ParameterError(f"obstacles: obstacle {i} must keep at least one step ({step:.6g}) from its "
                                     f"own periodic image along axis {a}: radius at most {(length - step) / 2:.6g} "
                                     f"(got {ob.radius:g}, box {length:g})")
        for j in range(i):
            other = obstacles[j]
            gap = periodic_distance(ob.centre, other.centre, box, walls) - ob.radius - other.radius
            if not gap >= step:
                raise ParameterError(f"obstacles: obstacles {j} and {i} overlap or are closer than one step "
                                     f"({step:.6g}) apart (gap {gap:.6g})")
