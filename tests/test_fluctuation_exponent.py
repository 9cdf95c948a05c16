"""Giant number fluctuations with a known exponent other than the Poisson one.

Points are laid out cell by cell on a grid of unit cells: ``k`` points in each cell, placed
anywhere inside it (away from its edges). A sub-box whose sides are whole numbers of cells,
aligned with the grid, then holds exactly the sum of the ``k`` of its cells: no Poisson
noise, only the variation of ``k`` that the construction puts in.

- Bands (2D): ``k`` is one random number per unit-wide column, ``Var k = s^2``. A square of
  side ``l`` spans ``l`` columns with ``l`` cells each: ``n = l sum_columns k``,
  ``Var n = l^2 l s^2`` and ``<n> = l^2 <k>``, so ``dn ~ l^(3/2) = <n>^(3/4)``: alpha = 3/4.
- Layers (3D): one ``k`` per unit-thick slab; a cube of side ``l`` spans ``l`` slabs of ``l^2``
  cells: ``Var n = l^4 l s^2``, ``<n> ~ l^3``, so ``dn ~ l^(5/2) = <n>^(5/6)``: alpha = 5/6.
- Phase-separated blocks: one ``k`` per block of ``64 x 64`` cells, and every sub-box inside
  one block: ``n = l^2 k``, so ``dn = l^2 s ~ <n>``: alpha = 1.

Each exponent must be found within four of its own errors, and the error must be small
enough to tell these answers from the Poisson 1/2 and from each other.
"""

from __future__ import annotations

import numpy as np
import pytest

from flocking.analysis import NumberFluctuations


def cell_points(rng: np.random.Generator, counts: np.ndarray) -> np.ndarray:
    """``counts[cell]`` points in each unit cell of the grid ``counts`` (any dimension),
    uniform in the cell's middle (5 % from each edge, so that no rounding moves a point
    into the next sub-box)."""
    corners = np.repeat(np.indices(counts.shape).reshape(counts.ndim, -1).T, counts.ravel(), axis=0)
    return corners + rng.uniform(0.05, 0.95, corners.shape)


def bands(rng, side: int, dim: int) -> np.ndarray:
    """One count in 1..5 per unit-wide slab across x: bands in 2D, layers in 3D."""
    k = rng.integers(1, 6, side).reshape((side,) + (1,) * (dim - 1))
    return cell_points(rng, np.broadcast_to(k, (side,) * dim))


def blocks(rng, side: int, block: int) -> np.ndarray:
    """One count in 1..5 per square block of ``block x block`` cells (2D)."""
    counts = rng.integers(1, 6, (side // block,) * 2)
    return cell_points(rng, np.repeat(np.repeat(counts, block, axis=0), block, axis=1))


#: name -> (points of one frame, box side, sub-box sides (whole cells, dividing the box), alpha)
CASES = {
    "bands-2d": (lambda rng: bands(rng, 256, 2), 256.0, [2, 4, 8, 16, 32, 64], 3 / 4),
    "layers-3d": (lambda rng: bands(rng, 48, 3), 48.0, [2, 3, 4, 6, 8, 12], 5 / 6),
    "blocks-2d": (lambda rng: blocks(rng, 256, 64), 256.0, [2, 4, 8, 16, 32, 64], 1.0),
}


@pytest.mark.parametrize("name", CASES)
def test_number_fluctuations_find_a_known_exponent(name):
    make, box, sizes, alpha = CASES[name]
    rng = np.random.default_rng(7)
    frames = [(box, make(rng)) for _ in range(8)]
    nf = NumberFluctuations(sizes=sizes).compute(frames)
    assert nf.fitted.all()
    # a useful error: it tells 3/4 from 5/6 (and from 1/2 and 1) at the 4-error level
    assert 0 < nf.alpha_error < (5 / 6 - 3 / 4) / 4
    assert abs(nf.alpha - alpha) < 4 * nf.alpha_error, (nf.alpha, nf.alpha_error)
