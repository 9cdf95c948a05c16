"""Sweeps: many independent runs over a grid of parameters, on Dask or in-process.

``spec`` reads and validates a sweep file, ``point`` runs one point into a record,
``ensembles`` groups points into jobs, ``executors`` run jobs here or on Dask, ``runner``
drives a sweep and stores each record as it arrives (``OUT/points/<id>.json``), ``results``
gathers them into an xarray Dataset and plots it. Dask, distributed and xarray (the
``sweep`` extra) are imported only when needed; :func:`require` turns a missing one into a
one-line error.
"""

from __future__ import annotations

import importlib

from ..model import ParameterError
from .spec import Point, SweepSpec, point_seed


def require(*modules: str) -> None:
    """Import ``modules`` or raise a :class:`ParameterError` telling how to install them."""
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError:
            raise ParameterError(f"sweep: needs the package {name!r}; "
                                 f"pip install '.[sweep]' in flocking's source folder") from None


__all__ = ["Point", "SweepSpec", "point_seed", "require"]
