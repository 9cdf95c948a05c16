"""flocking: fast, reproducible simulations of the Vicsek family of flocking models.

>>> import flocking
>>> model = flocking.Model(dim=2, n=500, box=16.0, noise=0.5, seed=1)
>>> sim = flocking.Simulation(model)
>>> sim.run(20)
>>> sim.state.positions.shape
(500, 2)
"""

from .model import Model, ParameterError
from .simulation import Simulation
from .state import State
from .trajectory import Frame, Trajectory, open
from .writers import CheckpointWriter, GSDWriter, ObservablesWriter, Writer

__version__ = "0.1.0"


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
    "CheckpointWriter", "Frame", "GSDWriter", "Model", "ObservablesWriter", "ParameterError", "Simulation",
    "State", "Trajectory", "Writer", "animate", "open", "plot_frame", "__version__",
]
