"""A live window: a :class:`~flocking.writers.Writer` that redraws the flock while it runs.

>>> import flocking
>>> sim = flocking.Simulation(flocking.Model(n=50, box=6.0))
>>> sim.writers.append(LiveView(every=5))   # on a machine without a display it says so
>>> sim.run(10)                             # doctest: +SKIP

Where no display exists (no ``DISPLAY``/``WAYLAND_DISPLAY`` on Linux, or a
non-interactive matplotlib backend) the view prints one line and does nothing, so the run
carries on; closing the window also just stops the drawing.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from ..trajectory import Frame, static_parts
from ..writers import Writer, static_chunks


def display_problem() -> str | None:
    """Why no window can open here, or ``None`` if one can."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    import matplotlib
    from matplotlib.backends import BackendFilter, backend_registry

    backend = matplotlib.get_backend()
    batch = backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE)
    if backend.lower() in batch or "inline" in backend.lower():
        return f"matplotlib backend {backend!r} cannot open a window"
    return None


def frame_of(sim) -> Frame:
    """The simulation's current state as a :class:`~flocking.Frame` (positions centred),
    with its species, walls and obstacles as a trajectory file would give them."""
    state, model = sim.state, sim.model
    n, d = state.n, model.dim
    points = np.zeros((n, 3), np.float32)
    points[:, :d] = state.positions - np.asarray(model.box) / 2
    velocities = np.zeros((n, 3), np.float32)
    velocities[:, :d] = state.speeds[:, None] * state.headings
    return Frame(state.step, d, model.box, points, velocities, **static_parts(static_chunks(model), d))


class LiveView(Writer):
    """Redraw a window every ``every`` steps, at most ``max_fps`` times a second; particles
    coloured by ``color`` (``heading``, ``species``, or ``auto``: species if there are several)."""

    def __init__(self, every: int = 10, theme: str = "dark", max_fps: float = 30.0, size: float = 6.0,
                 stream=None, color: str = "auto"):
        from .colors import check_color

        self.every = max(1, int(every))
        self.theme = theme
        self.color = check_color(color)
        self.min_interval = 1.0 / max_fps
        self.size = size
        self.stream = stream
        self.scene = None
        self.message = None
        self._last = 0.0

    def _say(self, text: str) -> None:
        self.message = text
        print(f"flocking: --show: {text}; running without the live view",
              file=self.stream or sys.stderr, flush=True)

    def begin(self, sim) -> None:
        if self.scene is not None or self.message is not None:
            return
        problem = display_problem()
        if problem:
            self._say(problem)
            return
        try:
            import matplotlib.pyplot as plt

            frame = frame_of(sim)
            self.scene = _scene(frame, sim.parameters(), self.theme, self.size, self.color)
            self.scene.figure.canvas.manager.set_window_title(f"flocking: {sim.model}")
            plt.show(block=False)
            plt.pause(0.001)
        except Exception as err:  # a broken GUI toolkit must not stop the run
            self.scene = None
            self._say(f"the window could not open ({type(err).__name__}: {err})")

    def write(self, sim) -> None:
        if self.scene is None:
            return
        import matplotlib.pyplot as plt

        if not plt.fignum_exists(self.scene.figure.number):  # closed by the user
            self.scene = None
            return
        now = time.perf_counter()
        if now - self._last < self.min_interval:
            return
        self._last = now
        self.scene.draw(frame_of(sim))
        self.scene.figure.canvas.draw_idle()
        plt.pause(0.001)

    def close(self) -> None:
        if self.scene is not None:
            import matplotlib.pyplot as plt

            plt.close(self.scene.figure)
            self.scene = None


def _scene(frame, parameters, theme, size, color="auto"):
    from .scene import Scene

    return Scene.for_frame(frame, parameters, theme=theme, size=size, dpi=100, pyplot=True, color=color).draw(frame)
