"""Mean square displacement of unwrapped positions.

Positions are unwrapped from successive frames by the minimum image: the displacement
between two frames is taken as the shortest periodic one, which is right as long as
no particle moves more than half a box side between frames (``v0 dt * steps between
frames < L / 2``). ``MSD(lag) = < |r_i(t + lag) - r_i(t)|^2 >`` over particles and all
time origins, grouped by the step difference (frames need not be evenly spaced).

>>> import numpy as np
>>> frames = [(10.0, np.array([[x % 10, 1.0]]), np.array([[1.0, 0.0]])) for x in (0, 4, 8, 12)]
>>> msd = MeanSquareDisplacement().compute(frames, steps=[0, 1, 2, 3])  # tuples carry no step
>>> msd.lags.tolist(), msd.msd.tolist()
([1, 2, 3], [16.0, 64.0, 144.0])
"""

from __future__ import annotations

import numba
import numpy as np

from ..model import ParameterError
from . import _input
from ._base import Analysis, result


@numba.njit(cache=True, parallel=True)
def _pair_msd(a, b):
    n, d = a.shape
    total = 0.0
    for i in numba.prange(n):
        s = 0.0
        for k in range(d):
            x = b[i, k] - a[i, k]
            s += x * x
        total += s
    return total / n


def unwrap(frames) -> np.ndarray:
    """``(F, N, d)`` unwrapped positions (minimum-image steps between frames)."""
    first = frames[0]
    out = np.empty((len(frames), first.n, first.dim))
    out[0] = first.positions
    prev = first.positions
    for t in range(1, len(frames)):
        f = frames[t]
        if f.n != first.n or np.any(f.box != first.box):
            raise ParameterError("system: every frame must have the same particles and box")
        step = f.positions - prev
        step -= f.box * np.round(step / f.box)
        out[t] = out[t - 1] + step
        prev = f.positions
    return out


class MeanSquareDisplacement(Analysis):
    """MSD against lag (in steps).

    Parameters
    ----------
    max_lag: largest lag in steps (default: all).
    start, frames: the window (consecutive frames; do not thin them, or unwrapping fails).

    ``compute(system, steps=None)``: ``steps`` overrides the frames' steps (for inputs
    without steps, such as ``(box, points)`` tuples).
    """

    _keys = ("lags", "msd", "origins", "num_frames")

    def __init__(self, max_lag=None, start=None, frames=None):
        if max_lag is not None and (isinstance(max_lag, bool) or not isinstance(max_lag, (int, np.integer))
                                    or max_lag < 1):
            raise ParameterError(f"max_lag: must be a whole number of steps >= 1 (got {max_lag!r})")
        _input.window_start(start, [0], 1)
        self.max_lag, self.start, self.frames = max_lag, start, _input.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"max_lag": self.max_lag, "start": self.start, "frames": self.frames}

    lags = result("lags", "Lags in steps.")
    msd = result("msd", "Mean square displacement per lag.")
    origins = result("origins", "Number of time origins averaged per lag.")
    num_frames = result("num_frames", "Number of frames used.")

    def compute(self, system, steps=None) -> MeanSquareDisplacement:
        frames = _input.as_frames(system)
        if steps is not None:
            steps = np.asarray(steps, dtype=np.int64)
            if steps.shape != (len(frames),) or np.any(np.diff(steps) <= 0):
                raise ParameterError(f"steps: must be {len(frames)} increasing whole numbers")
            frames = _input.Frames(frames, lambda f: f, steps)
        frames = _input.select(frames, self.start, self.frames)
        steps = np.asarray(frames.steps)
        if len(frames) < 2:
            raise ParameterError("system: the MSD needs at least two frames")
        if np.any(np.diff(steps) <= 0):
            raise ParameterError("system: frame steps must increase (give steps=... for inputs without steps)")
        pos = unwrap(frames)
        sums: dict[int, list] = {}
        for t0 in range(len(frames) - 1):
            for t1 in range(t0 + 1, len(frames)):
                lag = int(steps[t1] - steps[t0])
                if self.max_lag is not None and lag > self.max_lag:
                    break
                entry = sums.setdefault(lag, [0.0, 0])
                entry[0] += _pair_msd(pos[t0], pos[t1])
                entry[1] += 1
        lags = np.array(sorted(sums), dtype=np.int64)
        self._store(lags=lags, msd=np.array([sums[k][0] / sums[k][1] for k in lags]),
                    origins=np.array([sums[k][1] for k in lags]), num_frames=len(frames))
        return self

    def plot(self, ax=None):
        """MSD against lag, log-log, with slopes 1 and 2 for reference."""
        ax = self._axis(ax)
        ax.loglog(self.lags, self.msd, "o-", ms=3, label="MSD")
        x = self.lags.astype(float)
        ax.loglog(x, self.msd[0] * (x / x[0]) ** 2, ":", color="gray", label="ballistic ~ t^2")
        ax.loglog(x, self.msd[-1] * (x / x[-1]), "--", color="gray", label="diffusive ~ t")
        ax.set_xlabel("lag (steps)")
        ax.set_ylabel("MSD")
        ax.legend(loc="best")
        return ax
