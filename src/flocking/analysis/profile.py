"""Density profile along the mean direction of motion, and travelling bands.

Bands form perpendicular to the mean velocity, which in a periodic box settles along a
box axis; the profile is taken along the axis closest to the mean heading (or the one
given). Each frame's profile is the number density in slabs of width ``bin_width``.
A band is a run of slabs (periodic) where the profile, smoothed by a Gaussian of one
slab, exceeds ``(1 + threshold)`` times the mean density, with a peak above four
times the shot noise. A band's width is its equivalent width: its excess mass over the
gas (the median density outside bands) divided by its (smoothed) peak excess, which
is the exact width of a flat band. The band speed is the shift that best overlays two successive
profiles (periodic cross-correlation, refined by a parabola), over the steps between
them, counted positive along the mean heading; it is only meaningful when bands move
less than half their spacing between frames.

>>> import numpy as np
>>> rng = np.random.default_rng(4)
>>> x = np.r_[rng.uniform(0, 40, 4000), rng.uniform(10, 15, 4000)]   # one band at x in [10, 15)
>>> pts = np.c_[x, rng.uniform(0, 20, len(x))]
>>> u = np.tile([1.0, 0.0], (len(x), 1))
>>> dp = DensityProfile(bin_width=1.0).compute((np.array([40.0, 20.0]), pts, u))
>>> dp.axis_used, dp.band_count, round(dp.band_width)
(0, 1, 5)
"""

from __future__ import annotations

import numpy as np

from ..model import ParameterError
from . import _input
from ._base import Analysis, positive, result


def smooth(profile: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Periodic Gaussian smoothing (sigma in bins)."""
    n = len(profile)
    k = np.fft.rfftfreq(n) * 2 * np.pi
    return np.fft.irfft(np.fft.rfft(profile) * np.exp(-0.5 * (sigma * k) ** 2), n)


def bands(profile: np.ndarray, level: float) -> list[tuple[int, int]]:
    """Periodic runs of bins above ``level``: ``(first bin, length)`` each."""
    above = profile > level
    n = len(above)
    if above.all():
        return []
    if not above.any():
        return []
    start = int(np.argmin(above))  # a bin below the level: runs do not wrap from here
    rolled = np.roll(above, -start)
    runs, i = [], 0
    while i < n:
        if rolled[i]:
            j = i
            while j < n and rolled[j]:
                j += 1
            runs.append(((i + start) % n, j - i))
            i = j
        else:
            i += 1
    return runs


def band_widths(raw: np.ndarray, smoothed: np.ndarray, runs) -> np.ndarray:
    """Equivalent width (in bins) of each run: excess mass over the gas / peak excess."""
    n = len(raw)
    regions = [(r[0] + np.arange(-2, r[1] + 2)) % n for r in runs]
    outside = np.ones(n, bool)
    for reg in regions:
        outside[reg] = False
    gas = np.median(raw[outside]) if outside.any() else raw.min()
    return np.array([(raw[reg] - gas).sum() / (smoothed[reg].max() - gas) for reg in regions])


def best_shift(a: np.ndarray, b: np.ndarray) -> float:
    """Shift in bins (``-n/2 .. n/2``) that maps profile ``a`` onto ``b`` best."""
    n = len(a)
    xc = np.fft.irfft(np.conj(np.fft.rfft(a - a.mean())) * np.fft.rfft(b - b.mean()), n)
    k = int(np.argmax(xc))
    y0, y1, y2 = xc[(k - 1) % n], xc[k], xc[(k + 1) % n]
    denom = y0 - 2 * y1 + y2
    frac = 0.5 * (y0 - y2) / denom if denom < 0 else 0.0
    shift = k + frac
    return shift - n if shift > n / 2 else shift


class DensityProfile(Analysis):
    """Density along the mean direction of motion; band count, width and speed.

    Parameters
    ----------
    axis: box axis to profile along (default: the one closest to the mean heading).
    bin_width: slab width (default: at least 1, wide enough for 50 particles per slab on
        average, and at least 8 slabs).
    threshold: a band is denser than ``(1 + threshold)`` times the mean density.
    start, frames: the window.
    """

    _keys = ("axis_used", "direction", "x", "density", "band_count", "band_width", "band_widths", "band_speed",
             "band_speeds", "num_frames")

    def __init__(self, axis=None, bin_width=None, threshold=0.5, start=None, frames=None):
        if axis is not None and (isinstance(axis, bool) or axis not in (0, 1, 2)):
            raise ParameterError(f"axis: must be 0, 1 or 2 (got {axis!r})")
        self.axis = axis
        self.bin_width = positive("bin_width", bin_width, allow_none=True)
        self.threshold = positive("threshold", threshold)
        _input.window_start(start, [0], 1)
        self.start, self.frames = start, _input.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"axis": self.axis, "bin_width": self.bin_width, "threshold": self.threshold,
                "start": self.start, "frames": self.frames}

    axis_used = result("axis_used", "Axis profiled.")
    direction = result("direction", "+1 or -1: sign of the mean heading along the axis.")
    x = result("x", "Slab centres along the axis.")
    density = result("density", "Number density per slab, last frame.")
    profiles = result("profiles", "(frames, slabs) number density of every frame.")
    band_count = result("band_count", "Number of bands in the last frame.")
    band_counts = result("band_counts", "Number of bands per frame.")
    band_width = result("band_width", "Mean width of the bands over all frames (NaN without bands).")
    band_widths = result("band_widths", "Widths of the bands of the last frame.")
    band_speed = result("band_speed", "Median band speed over successive frames (length per step).")
    band_speeds = result("band_speeds", "Speed between each pair of successive frames.")
    num_frames = result("num_frames", "Number of frames.")

    def compute(self, system) -> DensityProfile:
        frames = _input.select(_input.as_frames(system), self.start, self.frames)
        first = frames[0]
        axis = self.axis
        if axis is not None and axis >= first.dim:
            raise ParameterError(f"axis: must be below the dimension {first.dim} (got {axis})")
        total = np.zeros(first.dim)
        for f in frames:
            if f.headings is not None:
                total += f.headings.sum(axis=0)
        if axis is None:
            axis = int(np.argmax(np.abs(total)))
        direction = 1 if total[axis] >= 0 else -1
        length = first.box[axis]
        cross = float(np.prod(first.box)) / length
        width = self.bin_width
        if width is None:
            width = max(1.0, 50.0 / (first.n / np.prod(first.box) * cross))
        nbins = max(int(round(length / min(width, length / 8))), 8) if self.bin_width is None else \
            max(int(round(length / width)), 1)
        width = length / nbins
        volume = width * cross
        profiles, counts, widths_all, last_widths = [], [], [], []
        for f in frames:
            if f.dim != first.dim or np.any(f.box != first.box):
                raise ParameterError("system: every frame must have the same box")
            hist = np.bincount(np.minimum((f.positions[:, axis] / width).astype(np.int64), nbins - 1),
                               minlength=nbins) / volume
            profiles.append(hist)
            mean = f.n / (nbins * volume)
            smoothed = smooth(hist)
            noise = 0.53 * np.sqrt(mean * volume) / volume
            runs = [r for r in bands(smoothed, (1 + self.threshold) * mean)
                    if smoothed[(r[0] + np.arange(r[1])) % nbins].max() - mean > 4 * noise]
            counts.append(len(runs))
            last_widths = band_widths(hist, smoothed, runs) * width
            widths_all.extend(last_widths.tolist())
        profiles = np.array(profiles)
        steps = np.asarray(frames.steps)
        speeds = np.array([direction * best_shift(profiles[t], profiles[t + 1]) * width / (steps[t + 1] - steps[t])
                           for t in range(len(frames) - 1) if steps[t + 1] > steps[t]])
        self._store(axis_used=axis, direction=direction, x=(np.arange(nbins) + 0.5) * width, density=profiles[-1],
                    profiles=profiles, band_count=counts[-1], band_counts=np.array(counts),
                    band_width=float(np.mean(widths_all)) if widths_all else float("nan"),
                    band_widths=last_widths,
                    band_speed=float(np.median(speeds)) if len(speeds) else float("nan"),
                    band_speeds=speeds, num_frames=len(frames))
        return self

    def plot(self, ax=None):
        """The last frame's profile and the mean density."""
        ax = self._axis(ax)
        ax.plot(self.x, self.density, "-", lw=1.2, label="last frame")
        ax.axhline(self.density.mean(), color="gray", lw=0.6, label="mean")
        ax.set_xlabel("xyz"[self.axis_used] + " (along the mean heading)")
        ax.set_ylabel("number density")
        ax.set_title(f"{self.band_count} band(s)")
        ax.legend(loc="best")
        return ax
