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
>>> tables(Model(n=10, box=5.0, vision=2.0)).cone.round(6).tolist()  # cos(2) |cos(2)|
[-0.173178]
"""

from __future__ import annotations

import math
import typing

import numpy as np

from ..model import Model
from ..space import Space


class Features(typing.NamedTuple):
    """What the kernels compile in. ``extended``: any extension at all (walls, obstacles,
    per-species values, chirality, a field are then read from :class:`Tables`); the rest
    weigh or add to each neighbour pair: a ``coupling`` matrix, ``nematic`` alignment, a
    vision ``cone``, ``cohesion``."""

    extended: bool = False
    coupling: bool = False
    nematic: bool = False
    cone: bool = False
    cohesion: bool = False

    @property
    def weighted(self) -> bool:
        """Whether a neighbour pair is weighed or adds more than its heading."""
        return self.coupling or self.nematic or self.cone or self.cohesion


def ring_width(dim: int, features: Features) -> int:
    """Values a particle keeps in the delay ring (the CPU's and the GPU's layout): the
    others' heading sum and ``1 +`` their count, and with cohesion the pull, the push and
    the core count.

    >>> ring_width(2, Features()), ring_width(3, Features(extended=True, cohesion=True))
    (3, 11)
    """
    return dim + 1 + (2 * dim + 1 if features.cohesion else 0)


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
    - ``obstacles`` (M, d + 1): centre, radius;
    - ``bounds`` (S + 1, int64): the first id of each species, then ``N``;
    - ``species`` (S, 5): per species the noise, the alignment, the cosine and the sine
      of the turn ``omega dt`` (1 and 0 without chirality), and the field strength;
    - ``coupling`` (S, S): the weight of species ``b`` in the sum of species ``a``;
    - ``field`` (3): the field's unit direction (zeros without one);
    - ``cone`` (1): ``cos |cos|`` of the vision half-angle (-4 without a cone: every
      neighbour is seen, see :func:`flocking.rules.physics.sees`);
    - ``cohesion`` (5): the strength ``beta``, ``r_c^2``, ``r_e``, ``r_a`` and the slope
      ``1 / (4 (r_a - r_e))`` of the attraction-repulsion (zeros without cohesion);
    - ``bias`` (1): added to ``u . v`` before nematic alignment takes its sign: 0 with
      nematic alignment, 4 without (no sign flips; see
      :func:`flocking.rules.physics.neighbour`).
    """

    walls: np.ndarray
    half: np.ndarray
    obstacles: np.ndarray
    bounds: np.ndarray
    species: np.ndarray
    coupling: np.ndarray
    field: np.ndarray
    cone: np.ndarray
    cohesion: np.ndarray
    bias: np.ndarray


def tables(model: Model) -> Tables:
    """The :class:`Tables` of ``model``."""
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
    cone = np.array([cos_v * abs(cos_v) if model.vision < math.pi else -4.0])
    cohesion = np.zeros(5)
    if model.cohesion:
        rc, re, ra = model.cohesion_radii
        cohesion[:] = model.cohesion, rc * rc, re, ra, 1.0 / (4.0 * (ra - re))
    return Tables(walls=walls, half=Space.of(model).half, obstacles=obstacles,
                  bounds=np.concatenate([[0], np.cumsum(model.species_counts)]).astype(np.int64),
                  species=species, coupling=coupling, field=field, cone=cone, cohesion=cohesion,
                  bias=np.array([0.0 if model.alignment_rule == "nematic" else 4.0]))


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
