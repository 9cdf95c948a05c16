"""Mean square displacement of unwrapped positions, by FFT.

Positions are unwrapped from successive frames by the minimum image along periodic axes
(between walls a coordinate needs no unwrapping): the displacement between two frames is
taken as the shortest periodic one, which is right as long as no particle moves half a
periodic box side or more between frames. For a flocking run that bound is
known, ``speed x dt x (steps between frames) < L / 2``, and frames further apart are
refused (:class:`~flocking.ParameterError`). For other files it is estimated from the
data: when the largest minimum-image displacement between successive frames exceeds a
quarter of a box side, a ``RuntimeWarning`` says so (a spread of displacements reaching
past ``L / 2`` wraps some of them to near ``L / 2``; motion by almost exactly whole box
sides between frames cannot be seen in positions at all).

``MSD(lag) = < |r_i(t + lag) - r_i(t)|^2 >`` over particles and every pair of frames
``lag`` steps apart. Frames need not be evenly spaced: on a grid of the greatest common
step between frames, with ``w(t) = 1`` where a frame is,

    sum_t w(t) w(t+m) |r(t+m) - r(t)|^2 = (w * Q)(m) + (Q * w)(m) - 2 sum_i (r_i * r_i)(m),

``Q(t) = sum_i |r_i(t)|^2`` and ``*`` the correlation ``(a * b)(m) = sum_t a(t) b(t + m)``,
each one FFT (freud's method, extended to gaps): O(N T log T) for T grid points instead
of O(N T^2). Where the grid is much longer than the frames are many (an odd stop frame),
the pairs of frames are summed directly, O(N F^2) in compiled code; both give the same.
Lags are in steps (``lag_steps``) and in the model's time (``lag_times = lag_steps * dt``).

>>> import numpy as np
>>> frames = [(20.0, np.array([[x % 20, 1.0]]), np.array([[1.0, 0.0]])) for x in (8, 12, 16, 20)]
>>> msd = MeanSquareDisplacement().compute(frames, steps=[0, 1, 2, 3])  # tuples carry no step
>>> msd.lag_steps.tolist(), msd.msd.round(9).tolist()
([1, 2, 3], [16.0, 64.0, 144.0])
"""

from __future__ import annotations

import math
import warnings

import numba
import numpy as np

from ..model import ParameterError
from . import snapshots
from .base import Analysis, legend, log_ticks, positive, result

#: Bytes of FFT work space per chunk of particles.
_CHUNK_BYTES = 1 << 26


def unwrap(frames) -> tuple[np.ndarray, np.ndarray]:
    """``(positions, largest step)``: ``(F, N, d)`` positions unwrapped by minimum-image
    steps between successive frames, and the largest ``|step|`` along each axis."""
    first = frames[0]
    out = np.empty((len(frames), first.n, first.dim))
    out[0] = first.positions
    prev = first.positions
    largest = np.zeros(first.dim)
    for t in range(1, len(frames)):
        f = frames[t]
        if f.n != first.n or np.any(f.box != first.box):
            raise ParameterError("system: every frame must have the same particles and box")
        step = f.space.displacement(prev, f.positions)  # the minimum image along periodic axes only
        np.maximum(largest, np.abs(step).max(axis=0), out=largest)
        out[t] = out[t - 1] + step
        prev = f.positions
    return out, largest


def _correlate(a: np.ndarray, b: np.ndarray, size: int) -> np.ndarray:
    """``(a * b)(m) = sum_t a(t) b(t + m)`` for ``m = 0 .. len(a) - 1`` (zero-padded FFT)."""
    return np.fft.irfft(np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size), size)[: len(a)]


def grid_sums(pos: np.ndarray, where: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """``(sum over pairs of |dr|^2 per lag, pairs of frames per lag)`` for lags ``0 ..
    length - 1`` grid points, frame ``t`` of ``pos`` (F, N, d) lying at grid point
    ``where[t]``."""
    f, n, d = pos.shape
    size = 1 << int(math.ceil(math.log2(2 * length)))
    w = np.zeros(length)
    w[where] = 1.0
    q = np.zeros(length)
    q[where] = np.einsum("tnd,tnd->t", pos, pos)
    cross = np.zeros(size // 2 + 1)
    chunk = max(1, _CHUNK_BYTES // (16 * size * d))
    for i in range(0, n, chunk):
        g = np.zeros((size, min(chunk, n - i), d))
        g[where] = pos[:, i:i + chunk]
        spectrum = np.fft.rfft(g, axis=0)
        cross += np.einsum("knd,knd->k", spectrum.real, spectrum.real)
        cross += np.einsum("knd,knd->k", spectrum.imag, spectrum.imag)
    auto = np.fft.irfft(cross, size)[:length]
    sums = _correlate(w, q, size) + _correlate(q, w, size) - 2.0 * auto
    return sums, np.rint(_correlate(w, w, size))


@numba.njit(cache=True, parallel=True)
def _direct(pos, lag_of, nlags, nchunks):
    """Per lag index, ``sum over particles and pairs of frames of |dr|^2`` (pos: N, F, d)."""
    n, f, d = pos.shape
    out = np.zeros((nchunks, nlags))
    for c in numba.prange(nchunks):
        for i in range(c * n // nchunks, (c + 1) * n // nchunks):
            for t0 in range(f - 1):
                for t1 in range(t0 + 1, f):
                    k = lag_of[t0, t1]
                    if k >= 0:
                        s = 0.0
                        for a in range(d):
                            x = pos[i, t1, a] - pos[i, t0, a]
                            s += x * x
                        out[c, k] += s
    return out.sum(axis=0)


def direct_sums(pos: np.ndarray, where: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """The same as :func:`grid_sums`, summing every pair of frames."""
    lags = where[None, :] - where[:, None]
    lag_of = np.where(lags > 0, lags, -1).astype(np.int64)
    sums = _direct(np.ascontiguousarray(pos.transpose(1, 0, 2)), lag_of, length,
                   int(min(pos.shape[1], 8 * numba.get_num_threads())))
    return sums, np.bincount(lags[lags >= 0], minlength=length).astype(float)


def refuse_far_frames(model, gap: int, space) -> None:
    """Refuse frames ``gap`` steps apart when the run's particles can move half the box
    along a periodic axis."""
    if not space.periodic.any():
        return  # nothing to unwrap between walls
    half = float(space.lengths[space.periodic].min()) / 2
    reach = model.speed * model.dt * gap
    if reach >= half:
        every = snapshots.steps_within_half(model, 2 * half)
        advice = (f"use frames at most {every} steps apart (flocking run --every {every})" if every else
                  "speed x dt alone reaches half the box: no frame spacing can be unwrapped")
        raise ParameterError(f"system: frames {gap} steps apart let a particle move up to {reach:.4g} "
                             f"(speed x dt x steps), at least half the box side {2 * half:.4g}, so "
                             f"positions cannot be unwrapped for the MSD; {advice}")


def warn_far_frames(largest: np.ndarray, space) -> None:
    """Warn when the largest displacement between frames exceeds a quarter of a box side
    along a periodic axis."""
    box = space.lengths
    ratio = np.where(space.periodic, largest / box, 0.0)
    if np.any(ratio > 0.25):
        a = int(np.argmax(ratio))
        warnings.warn(f"MeanSquareDisplacement: particles move up to {largest[a]:.4g} between frames, more than "
                      f"a quarter of the box side {box[a]:.4g}; any that moved half of it or more were unwrapped "
                      "the wrong way and the MSD is too small: use frames closer together", RuntimeWarning,
                      stacklevel=3)


class MeanSquareDisplacement(Analysis):
    """MSD against lag.

    Parameters
    ----------
    max_lag
        Largest lag in steps (default: all).
    dt
        Time step of the data (default: the run's stored ``dt``, else 1).
    start, frames
        The window (consecutive frames; do not thin them, or unwrapping fails).

    Notes
    -----
    ``compute(system, steps=None)``: ``steps`` overrides the frames' steps (for inputs
    without steps, such as ``(box, points)`` tuples).
    """

    _keys = ("lag_steps", "lag_times", "msd", "origins", "dt_used", "max_frame_displacement", "num_frames")

    def __init__(self, max_lag=None, dt=None, start=None, frames=None):
        if max_lag is not None and (isinstance(max_lag, bool) or not isinstance(max_lag, (int, np.integer))
                                    or max_lag < 1):
            raise ParameterError(f"max_lag: must be a whole number of steps >= 1 (got {max_lag!r})")
        snapshots.window_start(start, [0], 1)
        self.max_lag, self.dt = max_lag, positive("dt", dt, allow_none=True)
        self.start, self.frames = start, snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"max_lag": self.max_lag, "dt": self.dt, "start": self.start, "frames": self.frames}

    lag_steps = result("lag_steps", "Lags in steps.")
    lag_times = result("lag_times", "Lags in the model's time: lag_steps * dt.")
    msd = result("msd", "Mean square displacement per lag.")
    origins = result("origins", "Number of pairs of frames averaged per lag.")
    dt_used = result("dt_used", "Time step used for lag_times.")
    max_frame_displacement = result("max_frame_displacement",
                                    "Largest minimum-image displacement between successive frames, per axis.")
    num_frames = result("num_frames", "Number of frames used.")

    def compute(self, system, steps=None) -> MeanSquareDisplacement:
        frames = snapshots.as_frames(system)
        if steps is not None:
            steps = np.asarray(steps, dtype=np.int64)
            if steps.shape != (len(frames),) or np.any(np.diff(steps) <= 0):
                raise ParameterError(f"steps: must be {len(frames)} increasing whole numbers")
            frames = snapshots.Frames(frames, lambda f: f, steps, frames.model)
        frames = snapshots.select(frames, self.start, self.frames)
        steps = np.asarray(frames.steps)
        if len(frames) < 2:
            raise ParameterError(f"system: the MSD needs at least two frames (got {len(frames)})")
        if np.any(np.diff(steps) <= 0):
            raise ParameterError("system: frame steps must increase (give steps=... for inputs without steps)")
        gaps = np.diff(steps)
        if frames.model is not None:  # refuse before reading every frame
            refuse_far_frames(frames.model, int(gaps.max()), frames[0].space)
        pos, largest = unwrap(frames)
        if frames.model is None:
            warn_far_frames(largest, frames[0].space)
        pos -= pos.mean(axis=0)  # small numbers: the FFT's rounding is relative to them
        unit = int(np.gcd.reduce(gaps))
        where = (steps - steps[0]) // unit
        length = int(where[-1]) + 1
        f = len(frames)
        fft = length * max(math.log2(length), 1.0) * 8
        sums, pairs = grid_sums(pos, where, length) if fft < f * f / 2 else direct_sums(pos, where, length)
        lags = np.arange(length, dtype=np.int64) * unit
        keep = (pairs > 0) & (lags > 0)
        if self.max_lag is not None:
            keep &= lags <= self.max_lag
        dt = snapshots.time_step(self.dt, frames.model)
        self._store(lag_steps=lags[keep], lag_times=lags[keep] * dt, msd=sums[keep] / (pairs[keep] * pos.shape[1]),
                    origins=pairs[keep].astype(np.int64), dt_used=dt, max_frame_displacement=largest,
                    num_frames=f)
        return self

    def plot(self, ax=None, theme=None):
        """MSD against lag time, log-log, with slopes 2 (ballistic) and 1 (diffusive) for reference."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        x = self.lag_times
        ax.loglog(x, self.msd, "o-", ms=3, lw=1, color=colours[0], label="MSD")
        ax.loglog(x, self.msd[0] * (x / x[0]) ** 2, ":", color=colours[-1], lw=1, label=r"$\propto\Delta t^2$")
        ax.loglog(x, self.msd[-1] * (x / x[-1]), "--", color=colours[-1], lw=1, label=r"$\propto\Delta t$")
        style.label_axes(ax, "lag", "msd")
        log_ticks(ax)
        legend(ax, theme)
        return ax
