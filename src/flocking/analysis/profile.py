"""Density profile across travelling bands: their direction, widths and speed.

Bands are stripes of high density, uniform along the stripe, that travel along their
normal. In a periodic box a stripe closes on itself only along a direction of the box's
periodic lattice: the density of a band is then a function of the phase
``phi = sum_a m_a x_a / L_a (mod 1)`` for a whole vector ``m``. The profile is taken
along one of these directions, in ``B`` slabs of equal phase (equal volume), each
``period / B`` wide, where ``period = 1 / |m / L|`` is the distance between two images
of a stripe along its normal.

**Direction.** Every lattice direction with entries -1, 0 or 1 along the periodic axes
is a candidate: the axes and the diagonals (in 2D ``(1, 0), (0, 1), (1, 1), (1, -1)``;
13 in 3D; none along an axis with walls, which no stripe can cross). A band along one
direction leaves the profile along any other flat (the phases of two independent
directions are independent for uniform points), so the band's own direction is the one
whose profile varies most: the ``contrast``, the variance of the relative density
``n_b / <n_b>`` over the slabs less its shot noise, averaged over the frames. When that
direction holds no significant band (below), the profile is taken along the candidate
closest to the mean heading instead (bands travel along it); ``direction_rule`` says
which. ``direction`` is the unit normal (the profile's ``x`` grows along it), ``angle``
its angle from +x in degrees (2D), ``lattice`` the vector ``m``.

**Candidates.** A candidate band is a run of slabs (periodic) where the relative density,
smoothed by a Gaussian of one slab, exceeds ``1 + threshold``.

**Significance.** Under the null hypothesis the state is homogeneous at the same density.
The excess count of a window of ``k`` slabs (the run and two slabs either side) over its
expectation, ``M = sum_window (n_b - e_b)``, then has mean 0 and a variance that the test
takes as the larger of two:

- the ideal gas: ``N`` independent uniform positions make the window's count
  binomial, ``Var M = N p (1 - p)`` exactly, ``p`` the window's share of the free volume
  (``k / B`` without obstacles);
- the fluctuations of this very state, measured across the band: a band is uniform along
  its stripe, so slabs along the stripe (``B`` of them, the same volume as the profile's,
  along the lattice directions closest to perpendicular to the profile's, an axis with
  walls included) see the state's density fluctuations and not its bands. ``Var M`` is
  the mean square excess of every ``k`` consecutive such slabs over all frames and those
  directions. This is what makes the test hold in ordered homogeneous states, whose
  giant number fluctuations exceed the ideal gas' by 10 to 100 times at these scales.

A candidate is a band when ``z = M / sqrt(Var M) >= z_min`` (default 5). The transverse
estimate assumes fluctuations of the same size along and across the motion; slabs of the
same shape, as along the two axes or the two diagonals of a square box, make it a
like-for-like comparison.

**Obstacles** take volume from some slabs: each slab's expected count ``e_b`` is ``N``
times its share of the free volume (measured on a fine grid), the density is per free
volume, and the relative density is ``n_b / e_b``. **Walls** bound no slab (only periodic
axes make up a direction).

**Width.** The width of the flat band that has the band's excess mass (over the gas: the
median relative density outside every band, summed over the window) and fits its slabs
best (least squares, a slab that the flat band covers in part holding that part): its
excess mass over its height. Exact for a flat band wherever it lies among the slabs (a
band of ``w`` slabs of excess ``h``: ``w h / h``); the centre is the flat band's. A flat
band two slabs wide fits as well as any narrower one inside the same slabs, so under 2.5
slabs the width is the band's excess mass over the mean excess of its slabs above the
candidate level instead (exact for a band that fills whole slabs); use narrower slabs
(``bin_width``) to resolve narrow bands.

**Speed.** The shift that best overlays two successive profiles (periodic
cross-correlation, refined by a parabola), over the time between them (steps times
``dt``), positive along the mean heading; only between frames that both hold a band, and
only meaningful when bands move less than half their period between frames. For a
flocking run, whose bands are made of particles moving at ``speed``, frames further apart
than half the period at that speed give no band speed (NaN) and a ``RuntimeWarning``.

Slab centres ``x`` are distances along ``direction`` in the input's coordinates,
``direction . r`` folded into one period from ``direction . origin`` (for an axis, the
coordinate itself: ``[-L/2, L/2)`` for GSD files, whose positions are centred).

>>> import numpy as np
>>> rng = np.random.default_rng(4)
>>> x = np.r_[rng.uniform(0, 40, 4000), rng.uniform(10, 15, 4000)]   # one band at x in [10, 15)
>>> pts = np.c_[x, rng.uniform(0, 20, len(x))]
>>> u = np.tile([1.0, 0.0], (len(x), 1))
>>> dp = DensityProfile(bin_width=1.0).compute((np.array([40.0, 20.0]), pts, u))
>>> dp.lattice, dp.angle, dp.band_count, round(dp.band_width), round(float(dp.band_centres[0]), 1)
((1, 0), 0.0, 1, 5, 12.5)
"""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import snapshots
from .base import Analysis, legend, positive, result, walls_text


def lattice_directions(space: Space) -> list[tuple[int, ...]]:
    """The candidate directions of bands in ``space``: whole vectors of entries -1, 0 and
    1, zero along axes with walls, the first non-zero entry positive (axes first).

    >>> lattice_directions(Space((8.0, 8.0)))
    [(1, 0), (0, 1), (1, 1), (1, -1)]
    >>> lattice_directions(Space((8.0, 8.0, 8.0), walls=(False, True, False)))
    [(1, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, -1)]
    """
    out = []
    for m in itertools.product((0, 1, -1), repeat=space.dim):
        nonzero = [v for v in m if v]
        if nonzero and nonzero[0] > 0 and not any(w and v for w, v in zip(space.walls, m)):
            out.append(m)
    return sorted(out, key=lambda m: (sum(map(abs, m)), [-abs(v) for v in m], [-v for v in m]))


class Direction:
    """A lattice direction ``m`` of ``space``: its unit normal, period and the phase of
    points (relative to the box's corner) in ``[0, 1)``."""

    def __init__(self, lattice, space: Space):
        self.lattice = tuple(int(v) for v in lattice)
        g = np.asarray(self.lattice) / space.lengths  # the reciprocal vector: phase = g . r
        self.period = float(1.0 / np.linalg.norm(g))
        self.normal = g * self.period
        self.axis = self.lattice.index(1) if sum(map(abs, self.lattice)) == 1 else None
        self._reciprocal = g

    def phase(self, positions: np.ndarray) -> np.ndarray:
        return (positions @ self._reciprocal) % 1.0

    def counts(self, positions: np.ndarray, bins: int) -> np.ndarray:
        slab = np.minimum((self.phase(positions) * bins).astype(np.int64), bins - 1)
        return np.bincount(slab, minlength=bins)

    def name(self) -> str:
        return "xyz"[self.axis] if self.axis is not None else "(" + ", ".join(map(str, self.lattice)) + ")"


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
    """``Var M`` of a window of slabs in a homogeneous state (see the module): the larger
    of the ideal gas' (``expected``: each slab's expected count) and the mean square
    excess of as many consecutive slabs of ``transverse`` (rows of ``B`` slab counts less
    their expectations, across the band), periodic."""

    def __init__(self, transverse: np.ndarray, expected: np.ndarray):
        self.expected = np.asarray(expected, dtype=float)
        self.n = float(self.expected.sum())
        c = np.asarray(transverse, dtype=float).reshape(-1, len(self.expected))
        self._csum = np.concatenate([np.zeros((len(c), 1)), np.cumsum(np.concatenate([c, c], axis=1), axis=1)],
                                    axis=1)
        self._cache: dict[int, float] = {}

    def measured(self, k: int) -> float:
        if k not in self._cache:
            b = len(self.expected)
            self._cache[k] = float(np.mean((self._csum[:, k:k + b] - self._csum[:, :b]) ** 2)) if len(self._csum) \
                else 0.0
        return self._cache[k]

    def __call__(self, window: np.ndarray) -> float:
        p = self.expected[window].sum() / self.n
        return max(self.n * p * (1 - p), self.measured(len(window)))


def find_bands(counts: np.ndarray, expected: np.ndarray, variance: NullVariance, threshold: float, z_min: float):
    """The significant bands of one profile of slab ``counts`` (``expected`` in a
    homogeneous state): ``(windows, z, runs)``, each window the slab indices (periodic)
    of a band and its two slabs either side."""
    b = len(counts)
    windows, zs, runs = [], [], []
    for first, length in runs_above(smooth(counts / expected), 1 + threshold):
        window = ((first + np.arange(-2, length + 2)) % b)[:b]
        v = variance(window)
        excess = (counts[window] - expected[window]).sum()
        z = excess / np.sqrt(v) if v > 0 else 0.0  # v = 0: the whole box, M = 0
        if z >= z_min:
            windows.append(window)
            zs.append(float(z))
            runs.append((first, length))
    return windows, np.array(zs), runs


def flat_band(excess: np.ndarray) -> tuple[float, float]:
    """``(width, centre)`` in slabs (the centre from the first slab's lower edge) of the
    flat band, of the same excess mass, that fits the slabs' ``excess`` best (least
    squares): a band of ``w`` slabs of height ``mass / w``, each slab holding its share of
    it, a slab that the band covers in part the part it covers. Exact for a flat band
    wherever it lies among the slabs.

    >>> edges = np.clip(np.minimum(np.arange(1, 11), 6.7) - np.maximum(np.arange(10), 2.3), 0, None)
    >>> [round(v, 6) for v in flat_band(2.0 * edges)]  # a band of 4.4 slabs from 2.3 to 6.7, height 2
    [4.4, 4.5]
    """
    mass = float(excess.sum())
    lower = np.arange(len(excess), dtype=float)
    weight = np.clip(excess, 0, None)
    guess = float((weight * (lower + 0.5)).sum() / weight.sum())

    def best(centres, widths):
        c, w = np.meshgrid(centres, widths, indexing="ij")
        cover = np.minimum(lower + 1, (c + w / 2)[..., None]) - np.maximum(lower, (c - w / 2)[..., None])
        model = mass / w[..., None] * np.clip(cover, 0, 1)
        cost = ((excess - model) ** 2).sum(axis=-1)
        i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
        return float(centres[i]), float(widths[j])

    centre, width = best(guess + np.linspace(-1, 1, 21), np.arange(0.25, len(excess) + 0.25, 0.25))
    centre, width = best(centre + np.linspace(-0.1, 0.1, 21), np.maximum(width + np.linspace(-0.25, 0.25, 51), 0.01))
    return width, centre


def band_shapes(relative: np.ndarray, windows, runs, level: float):
    """``(widths in slabs, centres in slabs)`` of the bands in ``windows`` of a profile of
    ``relative`` densities (1 on average), from each window's excess over the gas (the
    median relative density outside every band): the :func:`flat_band` that fits it, or,
    when that is under 2.5 slabs wide (a flat band of two slabs or less fits as well as
    any narrower one inside the same slabs), the equivalent width: the excess mass over
    the mean excess of the slabs above ``level`` (of the run, if none), exact for a flat
    band that fills whole slabs, and the excess-weighted centre."""
    outside = np.ones(len(relative), bool)
    for window in windows:
        outside[window] = False
    gas = np.median(relative[outside]) if outside.any() else relative.min()
    widths, centres = [], []
    for window, (first, length) in zip(windows, runs):
        excess = relative[window] - gas
        width, centre = flat_band(excess)
        if width < 2.5:
            top = relative[window] > level
            width = excess.sum() / (excess[top].mean() if top.any() else excess[2:2 + length].mean())
            weight = np.clip(excess, 0, None)
            centre = (weight * (np.arange(len(window)) + 0.5)).sum() / weight.sum()
        widths.append(width)
        centres.append(first - 2 + centre)  # the window starts two slabs before the run
    return np.array(widths), np.array(centres) % len(relative)


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


class Slabs:
    """The slab counts of every frame along every candidate direction, each binned into
    the numbers of slabs any candidate uses, and the free share of every slab."""

    def __init__(self, frames, directions: list[Direction], bins: dict[tuple, int]):
        space = frames[0].space
        self.directions, self.bins = directions, bins
        sizes = sorted(set(bins.values()))
        self.counts = {(d.lattice, b): [] for d in directions for b in sizes}
        for f in frames:
            if f.dim != space.dim or np.any(f.box != space.lengths):
                raise ParameterError("system: every frame must have the same box")
            for d in directions:
                for b in sizes:
                    self.counts[d.lattice, b].append(d.counts(f.positions, b))
        self.counts = {key: np.array(rows) for key, rows in self.counts.items()}
        self.share = {key: np.ones(key[1]) for key in self.counts}
        if space.obstacles:
            grid = space.grid()
            free = ~space.in_obstacle(grid)
            for d in directions:
                for b in sizes:
                    total = d.counts(grid, b)
                    self.share[d.lattice, b] = d.counts(grid[free], b) / np.maximum(total, 1)

    def expected(self, direction: Direction, bins: int) -> np.ndarray:
        """``(frames, bins)``: each slab's expected count in a homogeneous state."""
        share = self.share[direction.lattice, bins]
        totals = self.counts[direction.lattice, bins].sum(axis=1, keepdims=True)
        return np.maximum(totals * share / share.sum(), 1e-300)

    def contrast(self, direction: Direction) -> float:
        """The variance of the relative density over the slabs less its shot noise,
        averaged over the frames."""
        b = self.bins[direction.lattice]
        counts, expected = self.counts[direction.lattice, b], self.expected(direction, b)
        relative = counts / expected
        return float(np.mean(relative.var(axis=1) - (1.0 / expected).mean(axis=1)))

    def transverse(self, direction: Direction, bins: int) -> np.ndarray:
        """Rows of ``bins`` slab counts less their expectations along the directions
        closest to perpendicular to ``direction`` (those along its stripes)."""
        others = [d for d in self.directions if d.lattice != direction.lattice]
        if not others:
            return np.zeros((0, bins))
        tilt = np.array([abs(d.normal @ direction.normal) for d in others])
        rows = [self.counts[d.lattice, bins] - self.expected(d, bins) for d, t in zip(others, tilt)
                if t <= tilt.min() + 0.05]
        return np.concatenate(rows)


class DensityProfile(Analysis):
    """Density across travelling bands; their direction, widths and speed.

    Parameters
    ----------
    direction
        The direction to profile along: an axis (0, 1, 2) or a lattice vector such
        as ``(1, -1)`` (entries along periodic axes only). Default: found (see the module).
    bin_width
        Slab width (default: at least 1, wide enough for 50 particles per slab on
        average, and at least 8 slabs).
    threshold
        A candidate band is denser than ``(1 + threshold)`` times the mean density.
    z_min
        A band's excess mass must be at least ``z_min`` standard deviations of that of a
        homogeneous state (see the module).
    dt
        Time step of the data (default: the run's stored ``dt``, else 1).
    start, frames
        The window.
    """

    _keys = ("lattice", "direction", "angle", "axis_used", "period", "direction_rule", "heading_sign", "candidates",
             "contrasts", "x", "density", "band_count", "band_widths", "band_centres", "band_significance",
             "band_width", "band_speed", "band_speeds", "frames_with_bands", "dt_used", "num_frames")

    def __init__(self, direction=None, bin_width=None, threshold=0.5, z_min=5.0, dt=None, start=None, frames=None):
        self.direction_asked = check_direction(direction)
        self.bin_width = positive("bin_width", bin_width, allow_none=True)
        self.threshold = positive("threshold", threshold)
        self.z_min = positive("z_min", z_min)
        self.dt = positive("dt", dt, allow_none=True)
        snapshots.window_start(start, [0], 1)
        self.start, self.frames = start, snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"direction": self.direction_asked, "bin_width": self.bin_width, "threshold": self.threshold,
                "z_min": self.z_min, "dt": self.dt, "start": self.start, "frames": self.frames}

    lattice = result("lattice", "The lattice vector m of the direction profiled (phase = sum m_a x_a / L_a).")
    direction = result("direction", "Unit normal of the bands' stripes, along which the profile runs.")
    angle = result("angle", "Angle of direction from +x in degrees, in (-90, 90] (2D; NaN in 3D).")
    axis_used = result("axis_used", "The axis profiled along, or None along a diagonal.")
    period = result("period", "Length of the profile: the distance between images of a stripe along direction.")
    direction_rule = result("direction_rule", "How the direction was chosen: 'bands', 'heading', 'contrast' or "
                                              "'given'.")
    heading_sign = result("heading_sign", "+1 or -1: sign of the mean heading along direction.")
    candidates = result("candidates", "The lattice directions tested.")
    contrasts = result("contrasts", "Contrast of the profile along each candidate (see the module).")
    x = result("x", "Slab centres along direction, in the input's coordinates.")
    density = result("density", "Number density per slab (per free volume), last frame.")
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
        frames = snapshots.select(snapshots.as_frames(system), self.start, self.frames)
        first = frames[0]
        space = first.space
        candidates = [Direction(m, space) for m in lattice_directions(space)]
        if not candidates:
            raise ParameterError(f"system: has {walls_text(space)}, every axis: a band is a stripe across a periodic "
                                 "box, and this box has no periodic axis")
        asked = None
        if self.direction_asked is not None:
            asked = Direction(given_lattice(self.direction_asked, space), space)
            if asked.lattice not in [d.lattice for d in candidates]:
                candidates.append(asked)
        bins = {d.lattice: self._bins(d, first.n) for d in candidates}
        # the stripes of a band may run along an axis with walls: the slabs across a band there too
        across = [Direction(m, space) for m in lattice_directions(Space(space.box))]
        slabs = Slabs(frames, candidates + [d for d in across if d.lattice not in bins], bins)
        contrasts = np.array([slabs.contrast(d) for d in candidates])
        heading = sum((f.headings.sum(axis=0) for f in frames if f.headings is not None), np.zeros(first.dim))
        if asked is not None:
            chosen, rule = [d for d in candidates if d.lattice == asked.lattice][0], "given"
            found = self._bands(slabs, chosen)
        else:
            chosen = candidates[int(np.argmax(contrasts))]
            found, rule = self._bands(slabs, chosen), "bands"
            if not any(len(z) for _, z, _ in found[0]):
                rule = "contrast"
                if np.any(heading):
                    chosen = candidates[int(np.argmax([abs(heading @ d.normal) for d in candidates]))]
                    found, rule = self._bands(slabs, chosen), "heading"
        self._finish(frames, chosen, rule, heading, found, candidates, contrasts)
        return self

    def _bins(self, direction: Direction, n: int) -> int:
        """The number of slabs along ``direction``."""
        if self.bin_width is not None:
            return max(int(round(direction.period / self.bin_width)), 1)
        width = max(1.0, 50.0 * direction.period / n)  # 50 particles per slab on average
        return max(int(round(direction.period / min(width, direction.period / 8))), 8)

    def _bands(self, slabs: Slabs, direction: Direction):
        """``(found per frame, counts, expected, free share)`` of the slabs along ``direction``."""
        b = slabs.bins[direction.lattice]
        counts, expected = slabs.counts[direction.lattice, b], slabs.expected(direction, b)
        variance = NullVariance(slabs.transverse(direction, b), expected.mean(axis=0))
        found = [find_bands(c, e, variance, self.threshold, self.z_min) for c, e in zip(counts, expected)]
        return found, counts, expected, slabs.share[direction.lattice, b]

    def _finish(self, frames, direction: Direction, rule: str, heading, found_counts, candidates, contrasts):
        found, counts, expected, share = found_counts
        first = frames[0]
        nbins = counts.shape[1]
        width = direction.period / nbins
        sign = 1 if heading @ direction.normal >= 0 else -1
        widths_all = []
        for c, e, (windows, _, runs) in zip(counts, expected, found):
            widths, centres = band_shapes(c / e, windows, runs, 1 + self.threshold)
            widths_all.extend(widths * width)
        has = np.array([len(z) > 0 for _, z, _ in found])
        steps = np.asarray(frames.steps)
        dt = snapshots.time_step(self.dt, frames.model)
        speeds = np.full(len(frames) - 1, np.nan)
        pairs = has[:-1] & has[1:] & (np.diff(steps) > 0)
        model = frames.model
        far = False
        if model is not None and pairs.any():
            reach = model.speed * model.dt * np.diff(steps)
            if np.any(reach[pairs] >= direction.period / 2):
                far = True
                every = snapshots.steps_within_half(model, direction.period)
                warnings.warn(f"DensityProfile: frames {int(np.diff(steps)[pairs].max())} steps apart let bands "
                              f"move up to {reach[pairs].max():.4g} (speed x dt x steps), at least half the period "
                              f"{direction.period:.4g} of the profile, so their speed cannot be told; use frames "
                              f"at most {every} steps apart (flocking run --every {every})", RuntimeWarning,
                              stacklevel=3)
                pairs &= reach < direction.period / 2
        for t in np.flatnonzero(pairs):
            shift = best_shift(counts[t] / expected[t], counts[t + 1] / expected[t + 1])
            speeds[t] = sign * shift * width / ((steps[t + 1] - steps[t]) * dt)
        volume = np.prod(first.box) / nbins * share  # the free volume of each slab
        start = float(direction.normal @ first.origin)
        measured = speeds[np.isfinite(speeds)]
        angle = math.degrees(math.atan2(direction.normal[1], direction.normal[0])) if first.dim == 2 else math.nan
        notes = profile_notes(first.space, direction, rule, has, pairs, far, len(frames))
        if first.dim == 3:
            notes.append("angle: NaN in 3D, where a direction takes two angles: see direction")
        self._store(lattice=direction.lattice, direction=direction.normal, angle=angle, axis_used=direction.axis,
                    period=direction.period, direction_rule=rule, heading_sign=sign,
                    candidates=[d.lattice for d in candidates], contrasts=contrasts,
                    x=start + (np.arange(nbins) + 0.5) * width, density=counts[-1] / volume,
                    profiles=counts / volume, band_count=len(found[-1][1]),
                    band_counts=np.array([len(z) for _, z, _ in found]), band_widths=widths * width,
                    band_centres=start + centres * width, band_significance=found[-1][1],
                    band_width=float(np.mean(widths_all)) if widths_all else float("nan"),
                    band_speed=float(np.median(measured)) if len(measured) else float("nan"),
                    band_speeds=speeds, frames_with_bands=int(has.sum()), dt_used=dt, num_frames=len(frames),
                    notes=notes)

    def plot(self, ax=None, theme=None):
        """The last frame's profile, the mean density, and its bands shaded."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        ax.plot(self.x, self.density, "-", lw=1.2, color=colours[0], label="last frame")
        ax.axhline(np.nanmean(self.density), color=colours[-1], lw=0.8, ls="--", label="mean")
        step = self.x[1] - self.x[0] if len(self.x) > 1 else 1.0
        low, high = self.x[0] - step / 2, self.x[-1] + step / 2
        widths = ", ".join(f"{w:.3g}" for w in self.band_widths)
        label = f"band{'s' * (len(self.band_widths) > 1)}, width{'s' * (len(self.band_widths) > 1)} {widths}"
        for i, (centre, w) in enumerate(zip(self.band_centres, self.band_widths)):
            for shift in (-(high - low), 0.0, high - low):  # a band across the boundary shows at both ends
                if centre + shift + w / 2 > low and centre + shift - w / 2 < high:
                    ax.axvspan(centre + shift - w / 2, centre + shift + w / 2, color=colours[1], alpha=0.25, lw=0,
                               label=label if i == 0 and shift == 0 else None)
        ax.set_xlim(low, high)
        toward = "+" if self.heading_sign > 0 else "-"
        if self.axis_used is not None:
            a = "xyz"[self.axis_used]
            style.label_axes(ax, f"${a}$, heading toward {toward}${a}$", rf"density $\rho({a})$")
        else:
            along = ", ".join(map(str, self.lattice))
            turn = f" ({self.angle:.0f}°)" if math.isfinite(self.angle) else ""
            style.label_axes(ax, f"$s$ along $({along})${turn}, heading toward {toward}$s$", r"density $\rho(s)$")
        legend(ax, theme)
        return ax


def check_direction(direction):
    """``None``, an axis or a tuple of whole numbers (not all zero), else a one-line error."""
    if direction is None:
        return None
    if isinstance(direction, (int, np.integer)) and not isinstance(direction, bool):
        if direction not in (0, 1, 2):
            raise ParameterError(f"direction: must be an axis 0, 1 or 2 or a lattice vector such as (1, 1) "
                                 f"(got {direction!r})")
        return int(direction)
    try:
        values = tuple(direction)
    except TypeError:
        values = ()
    if not (2 <= len(values) <= 3 and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                          for v in values) and any(values)):
        raise ParameterError(f"direction: must be an axis 0, 1 or 2 or a lattice vector of whole numbers such as "
                             f"(1, 1) (got {direction!r})")
    return tuple(int(v) for v in values)


def given_lattice(direction, space: Space) -> tuple[int, ...]:
    """The lattice vector of a direction asked for, checked against ``space``: its sign
    as the candidates have it (first non-zero entry positive), every entry along a
    periodic axis."""
    if isinstance(direction, int):
        if direction >= space.dim:
            raise ParameterError(f"direction: axis {direction} does not exist in {space.dim}D")
        direction = tuple(int(a == direction) for a in range(space.dim))
    if len(direction) != space.dim:
        raise ParameterError(f"direction: needs {space.dim} entries in {space.dim}D (got {direction!r})")
    if any(w and v for w, v in zip(space.walls, direction)):
        raise ParameterError(f"direction: must lie along periodic axes; this box has {walls_text(space)} "
                             f"(got {direction!r})")
    lead = next(v for v in direction if v)
    return tuple(v if lead > 0 else -v for v in direction)


def profile_notes(space: Space, direction: Direction, rule: str, has, pairs, far: bool, frames: int) -> list[str]:
    """Why the profile runs where it does, and why a band width or speed is NaN."""
    notes = []
    if rule == "heading":
        notes.append(f"no significant band along the direction of largest contrast: profiled along "
                     f"{direction.name()}, the candidate closest to the mean heading")
    elif rule == "contrast":
        notes.append("no significant band, and no velocities to point to a direction: profiled along the "
                     "direction of largest contrast")
    if any(space.walls):
        notes.append(f"{walls_text(space)}: bands are looked for along periodic directions only")
    if space.obstacles:
        notes.append("obstacles: each slab's density is per free volume, and its expected count in a homogeneous "
                     "state is in proportion to it")
    if not has.any():
        notes.append(f"band_width, band_speed: NaN, no significant band in {frames} frame{'s' * (frames > 1)}")
    elif not np.any(pairs):
        why = ("the frames holding bands are further apart than bands can be followed" if far else
               "no two successive frames both hold a band" if frames > 1 else "a single frame has no speed")
        notes.append(f"band_speed: NaN, {why}")
    return notes
