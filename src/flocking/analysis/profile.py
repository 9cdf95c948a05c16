"""Density profile along the mean direction of motion, and travelling bands.

Bands form perpendicular to the mean velocity, which in a periodic box settles along a
box axis; the profile is taken along the axis closest to the mean heading (or the one
given), in ``B`` slabs of width ``bin_width``. Slab centres ``x`` are in the input's
coordinates (``[-L/2, L/2)`` for GSD files, whose positions are centred in the box).

**Candidates.** A candidate band is a run of slabs (periodic) where the profile, smoothed
by a Gaussian of one slab, exceeds ``(1 + threshold)`` times the mean density.

**Significance.** Under the null hypothesis the state is homogeneous at the same density.
The excess count of a window of ``k`` slabs (the run and two slabs either side) over its
mean, ``M = sum_window (n_b - nbar)``, then has mean 0 and a variance that the test
takes as the larger of two:

- the ideal gas: ``N`` independent uniform positions make the window's count
  binomial, ``Var M = k nbar (1 - k / B)`` exactly;
- the fluctuations of this very state, measured across the direction of motion: a band
  is uniform across the box, so slabs perpendicular to the other axes (``B`` of them,
  the same volume as the profile's slabs) see the state's density fluctuations and not
  its bands. ``Var M`` is the mean square excess of every ``k`` consecutive such slabs
  over all frames and other axes. This is what makes the test hold in ordered
  homogeneous states, whose giant number fluctuations exceed the ideal gas' by 10 to
  100 times at these scales.

A candidate is a band when ``z = M / sqrt(Var M) >= z_min`` (default 5). The transverse
estimate assumes fluctuations of the same size along and across the motion; slabs of
the same shape, as in a square or cubic box, make it a like-for-like comparison.

**Width.** The equivalent width of each band: its excess mass over the gas (the median
slab outside every band), summed over the window, divided by its height, the mean excess
over the gas of the window's slabs above the candidate level (else of the run's slabs).
It is exact for a flat band (a band of ``w`` slabs of excess ``h``: ``w h / h``).

**Speed.** The shift that best overlays two successive profiles (periodic
cross-correlation, refined by a parabola), over the time between them (steps times
``dt``), positive along the mean heading; only between frames that both hold a band, and
only meaningful when bands move less than half their spacing between frames. For a
flocking run, whose bands are made of particles moving at ``speed``, frames further apart
than ``L / 2`` at that speed give no band speed (NaN) and a ``RuntimeWarning``.

>>> import numpy as np
>>> rng = np.random.default_rng(4)
>>> x = np.r_[rng.uniform(0, 40, 4000), rng.uniform(10, 15, 4000)]   # one band at x in [10, 15)
>>> pts = np.c_[x, rng.uniform(0, 20, len(x))]
>>> u = np.tile([1.0, 0.0], (len(x), 1))
>>> dp = DensityProfile(bin_width=1.0).compute((np.array([40.0, 20.0]), pts, u))
>>> dp.axis_used, dp.band_count, round(dp.band_width), round(float(dp.band_centres[0]), 1)
(0, 1, 5, 12.5)
"""

from __future__ import annotations

import warnings

import numpy as np

from ..model import ParameterError
from . import _input
from ._base import Analysis, legend, positive, result


def smooth(profile: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Periodic Gaussian smoothing (sigma in bins)."""
    n = len(profile)
    k = np.fft.rfftfreq(n) * 2 * np.pi
    return np.fft.irfft(np.fft.rfft(profile) * np.exp(-0.5 * (sigma * k) ** 2), n)


def runs_above(profile: np.ndarray, level: float) -> list[tuple[int, int]]:
    """Periodic runs of bins above ``level``: ``(first bin, length)`` each."""
    above = profile > level
    n = len(above)
    if above.all() or not above.any():
        return []
    start = int(np.argmin(above))  # a bin below the level: runs do not wrap from here
    rolled = np.roll(above, -start)
    edges = np.flatnonzero(np.diff(np.r_[0, rolled.astype(np.int8), 0]))
    return [((int(a) + start) % n, int(b - a)) for a, b in zip(edges[::2], edges[1::2])]


class NullVariance:
    """``Var M`` of a window of ``k`` slabs in a homogeneous state (see the module): the
    larger of the ideal gas' and the mean square excess of ``k`` consecutive slabs of
    ``transverse`` (rows of ``B`` slab counts across the motion), periodic."""

    def __init__(self, transverse: np.ndarray, nbins: int, mean: float):
        self.nbins, self.mean = nbins, mean
        c = transverse - transverse.mean(axis=1, keepdims=True)
        self._csum = np.concatenate([np.zeros((len(c), 1)), np.cumsum(np.concatenate([c, c], axis=1), axis=1)],
                                    axis=1)
        self._cache: dict[int, float] = {}

    def __call__(self, k: int) -> float:
        if k not in self._cache:
            b = self.nbins
            gas = k * self.mean * (1 - k / b)
            measured = float(np.mean((self._csum[:, k:k + b] - self._csum[:, :b]) ** 2)) if len(self._csum) else 0.0
            self._cache[k] = max(gas, measured)
        return self._cache[k]


def find_bands(counts: np.ndarray, variance: NullVariance, threshold: float, z_min: float):
    """The significant bands of one profile of slab ``counts``: ``(windows, z, runs)``,
    each window the slab indices (periodic) of a band and its two slabs either side."""
    b = len(counts)
    mean = counts.mean()
    smoothed = smooth(counts.astype(float))
    windows, zs, runs = [], [], []
    for first, length in runs_above(smoothed, (1 + threshold) * mean):
        window = ((first + np.arange(-2, length + 2)) % b)[:b]
        v = variance(len(window))
        z = (counts[window] - mean).sum() / np.sqrt(v) if v > 0 else 0.0  # v = 0: the whole box, M = 0
        if z >= z_min:
            windows.append(window)
            zs.append(float(z))
            runs.append((first, length))
    return windows, np.array(zs), runs


def band_shapes(counts: np.ndarray, windows, runs, level: float):
    """``(equivalent widths in slabs, centres in slabs)`` of the bands in ``windows``."""
    outside = np.ones(len(counts), bool)
    for window in windows:
        outside[window] = False
    gas = np.median(counts[outside]) if outside.any() else counts.min()
    widths, centres = [], []
    for window, (first, length) in zip(windows, runs):
        excess = counts[window] - gas
        top = counts[window] > level
        height = excess[top].mean() if top.any() else excess[2:2 + length].mean()
        widths.append(excess.sum() / height)
        offsets = np.arange(-2, len(window) - 2) + 0.5  # slab centres from the run's first slab
        weight = np.clip(excess, 0, None)
        centres.append(first + (weight * offsets).sum() / weight.sum())
    return np.array(widths), np.array(centres) % len(counts)


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
    """Density along the mean direction of motion; significant bands, their widths and speed.

    Parameters
    ----------
    axis: box axis to profile along (default: the one closest to the mean heading).
    bin_width: slab width (default: at least 1, wide enough for 50 particles per slab on
        average, and at least 8 slabs).
    threshold: a candidate band is denser than ``(1 + threshold)`` times the mean density.
    z_min: a band's excess mass must be at least ``z_min`` standard deviations of that of a
        homogeneous state (see the module).
    dt: time step of the data (default: the run's stored ``dt``, else 1).
    start, frames: the window.
    """

    _keys = ("axis_used", "direction", "x", "density", "band_count", "band_widths", "band_centres",
             "band_significance", "band_width", "band_speed", "band_speeds", "frames_with_bands", "dt_used",
             "num_frames")

    def __init__(self, axis=None, bin_width=None, threshold=0.5, z_min=5.0, dt=None, start=None, frames=None):
        if axis is not None and (isinstance(axis, bool) or axis not in (0, 1, 2)):
            raise ParameterError(f"axis: must be 0, 1 or 2 (got {axis!r})")
        self.axis = axis
        self.bin_width = positive("bin_width", bin_width, allow_none=True)
        self.threshold = positive("threshold", threshold)
        self.z_min = positive("z_min", z_min)
        self.dt = positive("dt", dt, allow_none=True)
        _input.window_start(start, [0], 1)
        self.start, self.frames = start, _input.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"axis": self.axis, "bin_width": self.bin_width, "threshold": self.threshold, "z_min": self.z_min,
                "dt": self.dt, "start": self.start, "frames": self.frames}

    axis_used = result("axis_used", "Axis profiled.")
    direction = result("direction", "+1 or -1: sign of the mean heading along the axis.")
    x = result("x", "Slab centres along the axis, in the input's coordinates.")
    density = result("density", "Number density per slab, last frame.")
    profiles = result("profiles", "(frames, slabs) number density of every frame.")
    band_count = result("band_count", "Number of significant bands in the last frame.")
    band_counts = result("band_counts", "Number of significant bands per frame.")
    band_widths = result("band_widths", "Equivalent widths of the bands of the last frame.")
    band_centres = result("band_centres", "Centres (excess-weighted) of the bands of the last frame, like x.")
    band_significance = result("band_significance", "z of each band of the last frame (see the module).")
    band_width = result("band_width", "Mean width of every band of every frame (NaN without bands).")
    band_speed = result("band_speed", "Median band speed (length per unit time) over successive frames that "
                                      "both hold a band (NaN without such a pair).")
    band_speeds = result("band_speeds", "Speed between each pair of successive frames (NaN unless both hold a band).")
    frames_with_bands = result("frames_with_bands", "Number of frames holding at least one band.")
    dt_used = result("dt_used", "Time step used for the speeds.")
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
        counts, transverse = [], []
        for f in frames:
            if f.dim != first.dim or np.any(f.box != first.box):
                raise ParameterError("system: every frame must have the same box")
            for a in range(f.dim):  # along the axis, then across it: B slabs of the same volume each
                slab = np.minimum((f.positions[:, a] * (nbins / f.box[a])).astype(np.int64), nbins - 1)
                (counts if a == axis else transverse).append(np.bincount(slab, minlength=nbins))
        counts = np.array(counts)
        variance = NullVariance(np.array(transverse).reshape(-1, nbins), nbins, first.n / nbins)
        found = [find_bands(c, variance, self.threshold, self.z_min) for c in counts]
        widths_all = []
        for c, (windows, _, runs) in zip(counts, found):
            widths, centres = band_shapes(c, windows, runs, (1 + self.threshold) * c.mean())
            widths_all.extend(widths * width)
        has = np.array([len(z) > 0 for _, z, _ in found])
        steps = np.asarray(frames.steps)
        dt = _input.time_step(self.dt, frames.model)
        speeds = np.full(len(frames) - 1, np.nan)
        pairs = has[:-1] & has[1:] & (np.diff(steps) > 0)
        model = frames.model
        if model is not None and pairs.any():
            reach = model.speed * model.dt * np.diff(steps)
            if np.any(reach[pairs] >= length / 2):
                every = _input.steps_within_half(model, length)
                warnings.warn(f"DensityProfile: frames {int(np.diff(steps)[pairs].max())} steps apart let bands "
                              f"move up to {reach[pairs].max():.4g} (speed x dt x steps), at least half the box "
                              f"side {length:.4g}, so their speed cannot be told; use frames at most {every} steps "
                              f"apart (flocking run --every {every})", RuntimeWarning, stacklevel=2)
                pairs &= reach < length / 2
        for t in np.flatnonzero(pairs):
            shift = best_shift(counts[t].astype(float), counts[t + 1].astype(float))
            speeds[t] = direction * shift * width / ((steps[t + 1] - steps[t]) * dt)
        profiles = counts / volume
        measured = speeds[np.isfinite(speeds)]
        self._store(axis_used=axis, direction=direction, x=first.origin[axis] + (np.arange(nbins) + 0.5) * width,
                    density=profiles[-1], profiles=profiles, band_count=len(found[-1][1]),
                    band_counts=np.array([len(z) for _, z, _ in found]), band_widths=widths * width,
                    band_centres=first.origin[axis] + centres * width, band_significance=found[-1][1],
                    band_width=float(np.mean(widths_all)) if widths_all else float("nan"),
                    band_speed=float(np.median(measured)) if len(measured) else float("nan"),
                    band_speeds=speeds, frames_with_bands=int(has.sum()), dt_used=dt, num_frames=len(frames))
        return self

    def plot(self, ax=None, theme=None):
        """The last frame's profile, the mean density, and its bands shaded."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        ax.plot(self.x, self.density, "-", lw=1.2, color=colours[0], label="last frame")
        ax.axhline(self.density.mean(), color=colours[-1], lw=0.8, ls="--", label="mean")
        step = self.x[1] - self.x[0] if len(self.x) > 1 else 1.0
        low, high = self.x[0] - step / 2, self.x[-1] + step / 2
        for i, (centre, w) in enumerate(zip(self.band_centres, self.band_widths)):
            for shift in (-(high - low), 0.0, high - low):  # a band across the boundary shows at both ends
                if centre + shift + w / 2 > low and centre + shift - w / 2 < high:
                    ax.axvspan(centre + shift - w / 2, centre + shift + w / 2, color=colours[1], alpha=0.25, lw=0,
                               label="band (equivalent width)" if i == 0 and shift == 0 else None)
        ax.set_xlim(low, high)
        a = "xyz"[self.axis_used]
        style.label_axes(ax, f"${a}$, heading toward {'+' if self.direction > 0 else '-'}${a}$",
                         rf"density $\rho({a})$")
        legend(ax, theme)
        return ax
