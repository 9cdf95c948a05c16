"""The static structure factor ``S(k) = |rho_k|^2 / N`` of the density, shell by shell.

``rho_k = sum_j exp(-i k . r_j)`` over the ``N`` particles of a frame, at the wavevectors
of the box, ``k_a = 2 pi n_a / L_a`` with whole ``n_a``, ``0 < |k| <= k_max`` (one of each
pair ``k``, ``-k``: their ``S`` are equal). A state without correlations (an ideal gas)
has ``S(k) = 1`` at every such ``k``; density waves and bands raise it at their
wavenumbers, and the giant number fluctuations of an ordered flock make it grow as ``k``
falls, since ``S(k)`` at ``k = 2 pi / l`` measures the variance of the count over lengths
``l`` in units of ``<n>``.

Shells: each wavevector falls in shell ``round(|k| / dk)``, ``dk = 2 pi / L_min``; a
shell's ``k`` is the mean ``|k|`` of its wavevectors and its ``S`` the mean of theirs.
Over frames, ``s`` is the mean and ``s_error`` the standard error of the frames' shell
values (frames counted as independent: frames closer in time than the flock's
correlation time make it too small); a single frame gives the scatter of its
wavevectors' values over their number instead.

From particles the sums are exact, computed as a product of the per-axis phase
factors in chunks of particles (``N x`` the number of wavevectors operations a frame).
From coarse-grained fields (:mod:`flocking.fields`) they come from the counts' FFT, as
if each particle sat at its bin's centre; binning multiplies the correlated part
``S - 1`` by the bin's window ``W(k) = prod_a sinc^2(k_a b_a / 2)`` (``b_a`` the bin
widths), so the fields give ``S = 1 + (S_bins - 1) / W``, which equals the particles'
``S`` where the density varies little within a bin (structure on lengths well above the
bin). ``k_max`` is then at most the grid's Nyquist ``pi / b`` (default: half of it,
where ``W >= 0.66`` in 2D).

Walls and obstacles: wavevectors are those of the whole box, along walls too (a density
uniform between walls has ``rho_k = 0`` there, as in a periodic box); what the walls and
obstacles do to the density (layers along walls, the obstacles' excluded area) is part
of the measured ``S``, and ``notes`` says so.

>>> import numpy as np
>>> rng = np.random.default_rng(4)
>>> frames = [(50.0, rng.uniform(0, 50, (5000, 2))) for _ in range(8)]
>>> sf = StructureFactor(k_max=3.0).compute(frames)
>>> bool(np.all(np.abs(sf.s - 1) < 5 * sf.s_error))  # an ideal gas: S = 1
True
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..model import ParameterError
from ..space import Space
from . import snapshots
from .base import Analysis, legend, log_ticks, result, walls_text
from .fieldinput import FieldCounts, is_fields

#: shells along the box's shortest side by default, in 2D and in 3D (from particles)
DEFAULT_SHELLS = {2: 32, 3: 12}
#: complex phase factors held at once while summing (chunks of particles)
CHUNK_VALUES = 1 << 22


def modes(space: Space, k_max: float) -> np.ndarray:
    """The whole ``n`` (``(modes, d)``, int) of the box's wavevectors ``2 pi n / L`` with
    ``0 < |k| <= k_max``, one of each pair ``+-k``: the last nonzero component positive.

    >>> modes(Space((10.0, 10.0)), 0.7).tolist()
    [[0, 1], [1, 0]]
    """
    top = np.floor(k_max * space.lengths / (2 * np.pi) * (1 + 1e-12)).astype(np.int64)
    axes = [np.arange(-m, m + 1) for m in top]
    n = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, space.dim)
    last = np.zeros(len(n), dtype=np.int64)
    for a in range(space.dim):  # the last nonzero component of each n
        last = np.where(n[:, a] != 0, n[:, a], last)
    k = 2 * np.pi * n / space.lengths
    keep = (last > 0) & (np.einsum("ij,ij->i", k, k) <= k_max * k_max * (1 + 1e-12))
    return n[keep]


def particle_sums(space: Space, positions: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``|rho_k|^2`` at the wavevectors ``2 pi n / L`` (``n`` from :func:`modes`), exact:
    the phase factors of each axis multiplied out as a matrix product, by chunks.

    >>> points = np.array([[0.0, 0.0], [5.0, 0.0]])
    >>> particle_sums(Space((10.0, 10.0)), points, np.array([[1, 0], [2, 0], [0, 1]])).round(12).tolist()
    [0.0, 4.0, 4.0]
    """
    dim = space.dim
    lo = n.min(axis=0)
    span = n.max(axis=0) - lo + 1
    rows = int(np.prod(span[:-1]))
    chunk = max(1, CHUNK_VALUES // int(rows + span[-1]))
    total = np.zeros((rows, int(span[-1])), dtype=np.complex128)
    for first in range(0, len(positions), chunk):
        x = positions[first:first + chunk]
        phases = [np.exp(-2j * np.pi * np.outer(x[:, a] / space.lengths[a], np.arange(lo[a], lo[a] + span[a])))
                  for a in range(dim)]
        left = phases[0]
        for p in phases[1:-1]:  # (chunk, rows) of the first d - 1 axes, x slowest
            left = (left[:, :, None] * p[:, None, :]).reshape(len(x), -1)
        total += left.T @ phases[-1]
    index = np.ravel_multi_index(tuple((n - lo).T), tuple(span))
    return np.abs(total.ravel()[index]) ** 2


def window(n: np.ndarray, shape) -> np.ndarray:
    """The nearest-bin window ``prod_a sinc^2(k_a b_a / 2)`` at ``k = 2 pi n / L`` on a
    grid of ``shape`` bins (x first): ``k_a b_a / 2 = pi n_a / m_a``.

    >>> window(np.array([[0, 0], [2, 0]]), (8, 8)).round(4).tolist()
    [1.0, 0.8106]
    """
    return np.prod(np.sinc(n / np.asarray(shape, dtype=np.float64)) ** 2, axis=1)


class StructureFactor(Analysis):
    """The structure factor ``S(k)`` in shells of ``|k|`` (see the module).

    Parameters
    ----------
    k_max
        Largest wavenumber, in units of ``1/R`` (default: from particles, 32 shells along
        the box's shortest side in 2D and 12 in 3D; from fields, half the grid's Nyquist
        ``pi / b``, at most the same). At least ``2 pi / L_max``, the box's smallest.
    start, frames
        The window (see :func:`flocking.analysis.snapshots.select`).
    """

    _keys = ("k", "s", "s_error", "counts", "k_max", "n", "num_frames", "source")

    def __init__(self, k_max=None, start=None, frames=None):
        if k_max is not None:
            if isinstance(k_max, bool) or not isinstance(k_max, numbers.Real) or not math.isfinite(k_max) \
                    or k_max <= 0:
                raise ParameterError(f"k_max: must be a wavenumber > 0, in units of 1/R (got {k_max!r})")
            k_max = float(k_max)
        snapshots.window_start(start, [0], 1)
        self.k_max_requested, self.start = k_max, start
        self.frames = snapshots.check_count("frames", frames)

    def parameters(self) -> dict:
        return {"k_max": self.k_max_requested, "start": self.start, "frames": self.frames}

    k = result("k", "The mean length of each shell's wavevectors, in units of 1/R.")
    s = result("s", "S(k) of each shell: the mean over its wavevectors and the frames.")
    s_error = result("s_error", "Standard error of s (see the module).")
    counts = result("counts", "Wavevectors in each shell.")
    wavevectors = result("wavevectors", "Every wavevector used, (modes, d), in units of 1/R.")
    s_modes = result("s_modes", "S at each of the wavevectors, averaged over the frames.")
    k_max = result("k_max", "The largest wavenumber used.")
    n = result("n", "Particles per frame.")
    num_frames = result("num_frames", "Number of frames averaged.")
    source = result("source", "'particles' or 'fields'.")

    def compute(self, system) -> StructureFactor:
        """``system``: frames of particles, or coarse-grained fields (a fields file or
        dataset, :mod:`flocking.fields`)."""
        if is_fields(system):
            fields = FieldCounts(system).window(self.start, self.frames)
            space, n_particles, source = fields.space, fields.n, "fields"
            nyquist = float(np.pi / np.max(fields.widths))
            k_max = self._k_max(space, min(nyquist / 2, self._default(space)))
            if k_max > nyquist * (1 + 1e-12):
                raise ParameterError(f"k_max: from fields of bin widths {fields.widths.tolist()}, must be at most "
                                     f"the grid's Nyquist wavenumber pi / b = {nyquist:.4g} (got {k_max:g})")
            n = modes(space, k_max)
            per_frame = self._from_fields(fields, n)
        else:
            chosen = snapshots.select(snapshots.as_frames(system), self.start, self.frames)
            first = chosen[0]
            space, n_particles, source = first.space, first.n, "particles"
            k_max = self._k_max(space, self._default(space))
            n = modes(space, k_max)
            rows = []
            for f in chosen:
                if f.dim != first.dim or np.any(f.box != first.box) or f.n != first.n:
                    raise ParameterError("system: every frame must have the same box and number of particles")
                rows.append(particle_sums(space, f.positions, n) / max(f.n, 1))
            per_frame = np.array(rows)
        k = 2 * np.pi * n / space.lengths
        size = np.sqrt(np.einsum("ij,ij->i", k, k))
        shell = np.rint(size / (2 * np.pi / np.min(space.lengths))).astype(np.int64)
        labels, inverse, counts = np.unique(shell, return_inverse=True, return_counts=True)
        by_shell = np.stack([np.bincount(inverse, weights=row, minlength=len(labels)) for row in per_frame]) / counts
        frames = len(per_frame)
        if frames >= 2:
            error = by_shell.std(axis=0, ddof=1) / np.sqrt(frames)
        else:
            spread = np.bincount(inverse, weights=per_frame[0] ** 2, minlength=len(labels)) / counts - by_shell[0] ** 2
            error = np.sqrt(np.maximum(spread, 0) / np.maximum(counts - 1, 1))
        self._store(k=np.bincount(inverse, weights=size) / counts, s=by_shell.mean(axis=0), s_error=error,
                    counts=counts, wavevectors=k, s_modes=per_frame.mean(axis=0), k_max=k_max, n=n_particles,
                    num_frames=frames, source=source, notes=self._notes(space, source, frames))
        return self

    @staticmethod
    def _default(space: Space) -> float:
        return 2 * np.pi * DEFAULT_SHELLS[space.dim] / float(np.min(space.lengths))

    def _k_max(self, space: Space, default: float) -> float:
        k_max = default if self.k_max_requested is None else self.k_max_requested
        smallest = 2 * np.pi / float(np.max(space.lengths))
        if k_max < smallest * (1 - 1e-12):
            raise ParameterError(f"k_max: must be at least 2 pi / L = {smallest:.4g}, the smallest wavenumber of the "
                                 f"box {space.lengths.tolist()} (got {k_max:g})")
        return float(k_max)

    @staticmethod
    def _from_fields(fields: FieldCounts, n: np.ndarray) -> np.ndarray:
        """``S`` of each frame at the wavevectors ``n``: the counts' FFT, bins deconvolved."""
        spatial = tuple(range(1, fields.counts.ndim))
        transform = np.fft.fftn(fields.counts, axes=spatial)  # (time, [z,] y, x)
        shape = fields.counts.shape[1:][::-1]  # bins per axis, x first
        index = tuple(np.mod(n[:, a], shape[a]) for a in reversed(range(fields.dim)))
        raw = np.abs(transform[(slice(None), *index)]) ** 2 / max(fields.n, 1)
        return 1 + (raw - 1) / window(n, shape)

    @staticmethod
    def _notes(space: Space, source: str, frames: int) -> list[str]:
        notes = []
        if any(space.walls):
            notes.append(f"{walls_text(space)}: wavevectors of the whole box along them; the density's layers at "
                         "the walls are part of S(k)")
        if space.obstacles:
            notes.append(f"{len(space.obstacles)} obstacle{'s' * (len(space.obstacles) > 1)}: their excluded area "
                         "is part of S(k), at wavenumbers about 2 pi / their size and above")
        if source == "fields":
            notes.append("from fields: S = 1 + (S_bins - 1) / W(k), exact where the density varies little within "
                         "a bin")
        if frames == 1:
            notes.append("one frame: s_error is the scatter of the shell's wavevectors over their number")
        return notes

    def plot(self, ax=None, theme=None):
        """``S(k)`` against ``k`` on log-log axes with its error bars, and the ideal
        gas' ``S = 1``."""
        from ..viz import style

        ax, theme = self._axes(ax, theme)
        colours = style.palette(theme)
        ax.errorbar(self.k, self.s, yerr=self.s_error, fmt="o", ms=3.5, lw=0.9, color=colours[0],
                    label=f"from {self.source}, {self.num_frames} frame{'s' * (self.num_frames != 1)}")
        ax.axhline(1.0, ls=":", lw=1, color=colours[-1], label="ideal gas, $S = 1$")
        ax.set_xscale("log")
        ax.set_yscale("log")
        style.label_axes(ax, "k", "structure")
        log_ticks(ax)
        legend(ax, theme)
        return ax
