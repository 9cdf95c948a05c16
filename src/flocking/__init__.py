"""flocking: fast, reproducible simulations of the Vicsek family of flocking models.

>>> import flocking
>>> model = flocking.Model(dim=2, n=500, box=16.0, noise=0.5, seed=1)
>>> sim = flocking.Simulation(model)
>>> sim.run(20)
>>> sim.state.positions.shape
(500, 2)
"""

import os
import sys

# LLVM's SLP vectoriser (off in numba by default) packs the independent summation lanes of
# the CPU kernels into SIMD registers. It never reorders an addition, so results do not
# depend on it; only speed does (and numba's cache keeps whichever code it compiled first).
if "NUMBA_SLP_VECTORIZE" not in os.environ:
    os.environ["NUMBA_SLP_VECTORIZE"] = "1"
    if "numba" in sys.modules:  # imported before us: make numba read its settings again
        sys.modules["numba"].config.reload_config()

from .ensemble import Ensemble  # noqa: E402
from .model import Model, ParameterError  # noqa: E402
from .simulation import NonFiniteError, Simulation  # noqa: E402
from .state import State  # noqa: E402
from .trajectory import Frame, Trajectory, open  # noqa: E402
from .writers import CheckpointWriter, GSDWriter, ObservablesWriter, Writer  # noqa: E402

__version__ = "0.1.0"


def _frame_png(frame: Frame) -> bytes:
    """A notebook shows a frame as a picture."""
    from .viz.notebook import frame_png

    return frame_png(frame)


def _trajectory_html(traj: Trajectory) -> str:
    """A notebook plays a trajectory as a small H.264 video."""
    from .viz.notebook import trajectory_html

    return trajectory_html(traj)


# The package joins the data to its pictures: trajectory.py, which the analysis and the
# pictures both read, imports neither (an import from it into viz closed a circle through them).
Frame._repr_png_ = _frame_png
Trajectory._repr_html_ = _trajectory_html


def __getattr__(name: str):
    # submodules with heavy dependencies (matplotlib, dask, ...) load when first used
    if name in ("analysis", "viz", "sweep"):
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    if name in ("plot_frame", "animate"):
        from . import viz

        return getattr(viz, name)
    raise AttributeError(f"module 'flocking' has no attribute {name!r}")


__all__ = [
    "CheckpointWriter", "Ensemble", "Frame", "GSDWriter", "Model", "NonFiniteError", "ObservablesWriter",
    "ParameterError", "Simulation", "State", "Trajectory", "Writer", "animate", "open", "plot_frame", "__version__",
]
