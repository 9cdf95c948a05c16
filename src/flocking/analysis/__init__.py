"""Measurements of a flock (docs/model.md, Observables), in the style of freud.

Each quantity is a class: parameters in the constructor, ``compute(system)`` returns the
object, results are read-only properties (:class:`NotComputedError` before ``compute``),
``plot(ax=None, theme=None)`` in the house style (:mod:`flocking.viz.style`) and
``to_dict()``. ``system`` is a trajectory (``flocking.open``), a GSD path or run folder, a
frame, a ``(box, points)`` pair, or a list of frames. Steps become time through the run's
``dt`` (``t = step * dt``); positions in results are in the input's coordinates.

>>> import numpy as np, flocking.analysis as fa
>>> points = np.random.default_rng(0).uniform(0, 10, (2000, 2))
>>> fa.Clusters(radius=0.01).compute((10.0, points)).num_clusters > 1900
True
"""

from .base import NotComputedError
from .boxcount import BoxCounting
from .clusters import Clusters
from .correlation import VelocityCorrelation
from .fluctuations import NumberFluctuations
from .msd import MeanSquareDisplacement
from .order import NematicOrder, PerSpecies, PolarOrder
from .profile import DensityProfile
from .structure import StructureFactor

__all__ = [
    "BoxCounting", "Clusters", "DensityProfile", "MeanSquareDisplacement", "NotComputedError",
    "NematicOrder", "NumberFluctuations", "PerSpecies", "PolarOrder", "StructureFactor",
    "VelocityCorrelation",
]
