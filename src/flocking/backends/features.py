"""What a model switches on, and the tables of values its kernels read: one definition for
the CPU and the CUDA backend.

:class:`Features` is fixed at compile time: the kernels of
:mod:`flocking.backends.cpu_kernels` and :mod:`flocking.backends.cuda_kernels` are built
for one value of it, so an extension that is off is not in the code at all, and the plain
model (``Features()``) runs the plain arithmetic. :func:`tables` gives the values a step
reads (:class:`Tables`: walls, obstacles, species, coupling, field, vision, cohesion), as
named arrays.

>>> from flocking import Model
>>> features(Model(n=10, box=5.0)) == Features()
True
>>> features(Model(n=10, box=5.0, vision=2.0, chirality=0.1))
Features(extended=True, coupling=False, nematic=False, cone=True, cohesion=False)
>>> dict(zip(PAIR, tables(Model(n=10, box=5.0, vision=2.0)).pair.round(6).tolist()))  # cone: cos(2) |cos(2)|
{'bias': 4.0, 'cone': -0.173178, 'rc2': 0.0, 're': 0.0, 'ra': 0.0, 'slope': 0.0}
"""

from __future__ import annotations

import math
import typing

import numpy as np

from ..model import Model
from ..rules import step as ring_layout
from ..rules import switch_constants
from ..rules.geometry import image_shift
from ..rules.physics import PAIR
from ..space import Space


class Features(typing.NamedTuple):
    """What the kernels compile in. ``extended``: any extension at all (walls, obstacles,
    per-species values, chirality, a field are then read from :class:`Tables`); the rest
    weigh or add to each neighbour pair: a ``coupling`` matrix, ``nematic`` alignment, a
    vision ``cone``, ``cohesion``. The kernels and the rules
    (:func:`flocking.rules.compile`) read each as a constant named in capitals
    (:meth:`flags`)."""

    extended: bool = False
    coupling: bool = False
    nematic: bool = False
    cone: bool = False
    cohesion: bool = False

    @property
    def weighted(self) -> bool:
        """Whether a neighbour pair is weighed or adds more than its heading: any feature
        but ``extended``."""
        return any(self[1:])

    def flags(self) -> dict[str, bool]:
        """Each feature as the constant a kernel is compiled with: its name in capitals.

        >>> Features(cone=True).flags()["CONE"]
        True
        """
        return switch_constants(self)


#: the pair weights that a value of :class:`Tables` makes exactly neutral (a coupling of 1,
#: the cone -4, a nematic ``bias`` of 4): a kernel may compile them in together for a model
#: that has only some of them (:func:`flocking.backends.cpu_kernels.variant`)
NEUTRAL = ("coupling", "nematic", "cone")


def ring_width(dim: int, features: Features) -> int:
    """Values a particle keeps in the delay ring (the CPU's and the GPU's layout): the
    others' heading sum and ``1 +`` their count, and with cohesion the pull, the push and
    the core count.

    >>> ring_width(2, Features()), ring_width(3, Features(extended=True, cohesion=True))
    (3, 11)
    """
    return ring_layout.width(dim, features.cohesion)


def features(model: Model) -> Features:
    """The :class:`Features` of ``model``."""
    on = model.extensions
    return Features(extended=bool(on), coupling="coupling" in on, nematic="nematic alignment" in on,
                    cone="vision" in on, cohesion="cohesion" in on)


class Tables(typing.NamedTuple):
    """The values of a model's extensions, as the kernels read them (float64; the CUDA
    backend converts them to its precision).

    - ``walls`` (d, int64): 1 along an axis closed by walls;
    - ``half`` (d): how far a displacement reaches before the minimum image folds it,
      ``L/2``, or infinite along walls;
    - ``shifts`` (d): what a periodic image copied across the box's end is shifted by,
      ``L``, or ``2L`` along walls (:func:`flocking.rules.geometry.image_shift`);
    - ``obstacles`` (M, d + 1): centre, radius;
    - ``bounds`` (S + 1, int64): the first id of each species, then ``N``;
    - ``species`` (S, 5): per species the noise, the alignment, the cosine and the sine
      of the turn ``omega dt`` (1 and 0 without chirality), and the field strength;
    - ``coupling`` (S, S): the weight of species ``b`` in the sum of species ``a``;
    - ``field`` (3): the field's unit direction (zeros without one);
    - ``beta`` (1): the strength of cohesion (0 without);
    - ``pair``: the values of the pair terms, named by
      :data:`flocking.rules.physics.PAIR`: ``bias``, added to ``u . v`` before nematic
      alignment takes its sign (0 with nematic alignment, 4 without: no sign flips; see
      :func:`flocking.rules.physics.neighbour`); ``cone``, ``cos |cos|`` of the vision
      half-angle (-4 without a cone: every neighbour is seen, see
      :func:`flocking.rules.physics.sees`); ``rc2`` (``r_c^2``), ``re``, ``ra`` and the
      ``slope`` ``1 / (4 (r_a - r_e))`` of cohesion's attraction-repulsion (zeros without
      cohesion).
    """

    walls: np.ndarray
    half: np.ndarray
    shifts: np.ndarray
    obstacles: np.ndarray
    bounds: np.ndarray
    species: np.ndarray
    coupling: np.ndarray
    field: np.ndarray
    beta: np.ndarray
    pair: np.ndarray


def tables(model: Model) -> Tables:
    """The :class:`Tables` of ``model``.

    >>> tb = tables(Model(n=10, box=(4.0, 6.0), boundary="periodic,wall"))
    >>> tb.half.tolist(), tb.shifts.tolist()
    ([2.0, inf], [4.0, 12.0])
    """
    d = model.dim
    walls = np.asarray(model.walls, dtype=np.int64)
    obstacles = np.array([[*o.centre, o.radius] for o in model.obstacles], dtype=np.float64).reshape(-1, d + 1)
    turn = [omega * model.dt for omega in model.species_values("chirality")]
    species = np.array([model.species_values("noise"), model.species_values("alignment"), [math.cos(a) for a in turn],
                        [math.sin(a) for a in turn], model.species_values("field_strength")], dtype=np.float64).T.copy()
    count = len(model.species_counts)
    coupling = np.ones((count, count)) if model.coupling is None else np.array(model.coupling, dtype=np.float64)
    field = np.zeros(3)
    if model.field is not None:
        field[:d] = model.field_direction
    cos_v = math.cos(model.vision)
    pair = dict(bias=0.0 if model.alignment_rule == "nematic" else 4.0,
                cone=cos_v * abs(cos_v) if model.vision < math.pi else -4.0, rc2=0.0, re=0.0, ra=0.0, slope=0.0)
    if model.cohesion:
        rc, re, ra = model.cohesion_radii
        pair.update(rc2=rc * rc, re=re, ra=ra, slope=1.0 / (4.0 * (ra - re)))
    shifts = np.array([image_shift(length, wall) for length, wall in zip(model.box, model.walls)])
    return Tables(walls=walls, half=Space.of(model).half, shifts=shifts, obstacles=obstacles,
                  bounds=np.concatenate([[0], np.cumsum(model.species_counts)]).astype(np.int64),
                  species=species, coupling=coupling, field=field, beta=np.array([float(model.cohesion)]),
                  pair=np.array([pair[name] for name in PAIR]))


class Step(typing.NamedTuple):
    """The scalar parameters of a step, as the CPU kernels read them (by name, in
    registers): ``R^2``, the noise, the alignment, ``dt``, ``k`` (0 for metric
    neighbours), the delay, vectorial noise, the backward update."""

    r2: float
    eta: float
    epsilon: float
    dt: float
    k: int
    delay: int
    vectorial: bool
    backward: bool


def step(model: Model) -> Step:
    """The :class:`Step` of ``model``.

    >>> step(Model(n=10, box=5.0, delay=3)).delay
    3
    """
    return Step(float(model.radius**2), float(model.noise), float(model.alignment), float(model.dt),
                int(model.k if model.neighbours == "topological" else 0), int(model.delay),
                model.noise_type == "vectorial", model.update == "backward")
