"""Coarse-grained fields (:mod:`flocking.fields`) as an input of the analysis.

A fields file (or the ``xarray.Dataset`` that :func:`flocking.fields.open` gives) holds
the count of particles per bin at every recorded step: the number fluctuations in
sub-boxes of whole bins follow from it without the particles
(:class:`~flocking.analysis.NumberFluctuations` takes it as its ``system``).
"""

from __future__ import annotations

import json
import os

import numpy as np

from ..model import ParameterError
from ..space import Space


def is_fields(system) -> bool:
    """Whether ``system`` is a fields file (a path ending in ``.nc``) or dataset."""
    if isinstance(system, (str, os.PathLike)):
        return os.fspath(system).endswith(".nc")
    return hasattr(system, "data_vars") and "count" in getattr(system, "data_vars", ())


class FieldCounts:
    """The counts of a fields input: ``counts`` ``(time, [z,] y, x)`` (float), ``steps``,
    ``widths`` (bin widths per axis, x first), ``space`` (box, walls, obstacles of the run,
    corner at 0) and ``n`` (particles)."""

    def __init__(self, system):
        if isinstance(system, (str, os.PathLike)):
            from ..fields import open as open_fields

            system = open_fields(system)
        ds = system
        self.counts = np.asarray(ds["count"].values, dtype=np.float64)
        self.steps = np.asarray(ds["step"].values, dtype=np.int64)
        self.widths = np.asarray(ds.attrs["bin_widths"], dtype=np.float64).ravel()
        box = np.asarray(ds.attrs["box"], dtype=np.float64).ravel()
        walls, obstacles = (False,) * len(box), ()
        params = json.loads(ds.attrs.get("parameters", "{}")).get("model")
        if params:
            from ..model import Model

            model = Model.from_dict(params)
            walls, obstacles = model.walls, Space.of(model).obstacles
        self.space = Space(tuple(box), walls, obstacles)
        self.n = int(round(self.counts[0].sum())) if len(self.counts) else 0
        if len(self.counts) == 0:
            raise ParameterError("system: the fields file holds no frame")

    @property
    def dim(self) -> int:
        return len(self.widths)

    def window(self, start, frames) -> FieldCounts:
        """The frames of a window, as :func:`flocking.analysis.snapshots.select` picks them."""
        from .snapshots import window_start

        first = window_start(start, self.steps if start is not None and not 0 < start < 1 else None,
                             len(self.steps))
        keep = slice(first if frames is None else max(first, len(self.steps) - frames), None)
        if len(self.steps[keep]) == 0:
            raise ParameterError(f"start: no frame left after start={start!r} (the last frame is at step "
                                 f"{int(self.steps[-1])})")
        out = object.__new__(FieldCounts)
        out.__dict__.update(self.__dict__, counts=self.counts[keep], steps=self.steps[keep])
        return out

    def bins_per_side(self, side: float) -> int:
        """How many bins a sub-box of ``side`` spans along every axis, or a one-line refusal
        when it is not a whole number of bins along each."""
        k = side / self.widths
        whole = np.round(k)
        if np.any(whole < 1) or np.any(np.abs(k - whole) > 1e-9 * whole) or np.any(whole != whole[0]):
            raise ParameterError(f"sizes: from fields, every side must be a whole number of bins (bin widths "
                                 f"{self.widths.tolist()}; got {side:g})")
        return int(whole[0])

    def block_counts(self, k: int) -> np.ndarray:
        """Counts of the whole sub-boxes of ``k x k`` bins, ``(time, boxes)``, the boxes in
        the order of :class:`flocking.analysis.fluctuations.SubBoxes` (x slowest)."""
        c = self.counts
        frame = c.shape[1:]
        whole = [m // k for m in frame]
        c = c[(slice(None), *(slice(0, w * k) for w in whole))]
        shape = [c.shape[0]]
        for w in whole:
            shape += [w, k]
        blocks = c.reshape(shape).sum(axis=tuple(range(2, 2 * len(whole) + 1, 2)))
        # (time, [z,] y, x) -> (time, x, y[, z]): x slowest, as np.indices over (x, y, z)
        return blocks.transpose(0, *range(blocks.ndim - 1, 0, -1)).reshape(len(c), -1)
