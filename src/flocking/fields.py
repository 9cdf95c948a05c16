"""Coarse-grained fields: the particles' count, polarisation and nematic sums per bin of a
grid, written every few steps into a netCDF file (docs/fields.md).

A :class:`Grid` of bin size ``b`` has ``m = max(1, round(L / b))`` bins of width ``L / m``
along each axis. Each backend sums its own arrays (``backend.fields(grid)``: a compiled
pass over the slots on the cpu backend, a kernel on the device arrays for cuda, NumPy on
the reference) into ``(species, channel, bin)``: per species the count, the heading sum
``sum u`` and, for nematic runs, the nematic products of
:func:`flocking.observables.moment_sums`. :class:`FieldsWriter` stores them with
dimensions ``(time, y, x)`` (3D: ``(time, z, y, x)``): ``count`` (particles per bin, whole
numbers), ``polarisation_x`` ... (the sums of the headings), ``nematic_*`` and, with several
species, the same per species with the species' name as a suffix. :func:`open` reads one
as an ``xarray.Dataset``.

>>> import numpy as np
>>> from flocking import Model, State
>>> model = Model(n=500, box=10.0, seed=2)
>>> grid = Grid.of(model, 2.5)
>>> grid.shape, grid.names()[:3]
((4, 4), ('count', 'polarisation_x', 'polarisation_y'))
>>> sums = bin_sums(grid, State.random(model))
>>> int(sums[0, 0].sum()), sums.shape
(500, (1, 3, 16))
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from .checks import ParameterError
from .writers import Writer

#: the file a run folder holds its fields in
FILENAME = "fields.nc"
#: the extra that brings netCDF4 and xarray
EXTRA = "pip install '.[sweep]' in flocking's source folder"
#: most bins a grid may have (a frame of 2**26 bins of 3 float64 channels is 1.5 GiB)
MAX_BINS = 2**26


@dataclasses.dataclass(frozen=True)
class Grid:
    """Bins per axis ``shape`` (x first) over ``box``; ``species`` blocks of ``width``
    channels (count, ``dim`` heading sums, then 2 (2D) or 6 (3D) nematic products if
    ``nematic``); ``bounds``: the species' first ids, then ``N``; ``names``: the species'."""

    shape: tuple[int, ...]
    box: tuple[float, ...]
    species: int = 1
    nematic: bool = False
    bounds: tuple[int, ...] = (0, 0)
    species_names: tuple[str, ...] = ("A",)

    @classmethod
    def of(cls, model, bin_size: float) -> Grid:
        """The grid of bin size about ``bin_size`` for ``model``; refused in one line if
        the size is not a positive number or makes more than :data:`MAX_BINS` bins."""
        try:
            size = float(bin_size)
        except (TypeError, ValueError):
            size = float("nan")
        if not np.isfinite(size) or size <= 0 or isinstance(bin_size, bool):
            raise ParameterError(f"fields: must be a bin size > 0, in units of length (got {bin_size!r})")
        shape = tuple(max(1, round(length / size)) for length in model.box)
        if np.prod(shape, dtype=float) > MAX_BINS:
            raise ParameterError(f"fields: a bin size of {size:g} makes {np.prod(shape, dtype=float):.3g} bins in "
                                 f"the box {model.box}; at most {MAX_BINS} (give a larger bin size)")
        counts = model.species_counts
        return cls(shape, tuple(float(x) for x in model.box), len(counts), model.alignment_rule == "nematic",
                   tuple(int(x) for x in np.concatenate([[0], np.cumsum(counts)])), tuple(model.species_names))

    @property
    def dim(self) -> int:
        return len(self.shape)

    @property
    def widths(self) -> tuple[float, ...]:
        return tuple(length / m for length, m in zip(self.box, self.shape))

    @property
    def bins(self) -> int:
        return int(np.prod(self.shape))

    @property
    def width(self) -> int:
        """Channels per species."""
        return 1 + self.dim + ((2 if self.dim == 2 else 6) if self.nematic else 0)

    def names(self) -> tuple[str, ...]:
        """The channels of a species block, as the file names them."""
        axes = "xyz"[: self.dim]
        nematic = ("nematic_cos", "nematic_sin") if self.dim == 2 else tuple(
            f"nematic_{a}{b}" for a, b in ("xx", "yy", "zz", "xy", "xz", "yz"))
        return ("count", *(f"polarisation_{a}" for a in axes), *(nematic if self.nematic else ()))

    def frame_shape(self) -> tuple[int, ...]:
        """A frame's array shape: ``(y, x)`` or ``(z, y, x)``."""
        return tuple(reversed(self.shape))


def bin_sums(grid: Grid, state) -> np.ndarray:
    """The sums ``(species, channel, bin)`` of a state (id order) in NumPy: the reference
    backend's, and the oracle the compiled passes are tested against. The bin rule is
    :func:`flocking.rules.geometry.cell_index`'s (clamped; NaN in the first bin)."""
    pos, head = np.asarray(state.positions, np.float64), np.asarray(state.headings, np.float64)
    flat = np.zeros(len(pos), dtype=np.int64)
    stride = 1
    for a, m in enumerate(grid.shape):
        with np.errstate(invalid="ignore"):
            f = pos[:, a] * (m / grid.box[a])
            index = np.where(f >= 1.0, np.where(f >= m, m - 1, np.floor(np.where(f >= 1.0, f, 0.0))), 0)
        flat += index.astype(np.int64) * stride
        stride *= m
    species = np.searchsorted(np.asarray(grid.bounds[1:]), np.arange(len(pos)), side="right")
    values = [np.ones(len(pos)), *head.T]
    if grid.nematic:
        u = head
        if grid.dim == 2:
            values += [u[:, 0] * u[:, 0] - u[:, 1] * u[:, 1], 2.0 * u[:, 0] * u[:, 1]]
        else:
            values += [u[:, a] * u[:, b] for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]
    out = np.zeros((grid.species, grid.width, grid.bins))
    for s in range(grid.species):
        mine = species == s
        for c, v in enumerate(values):
            out[s, c] = np.bincount(flat[mine], weights=v[mine], minlength=grid.bins)
    return out


def require_netcdf(what: str = "fields"):
    """netCDF4, or a one-line :class:`ParameterError` that names the extra to install."""
    try:
        import netCDF4
    except ImportError:
        raise ParameterError(f"{what}: writing fields needs netCDF4 (the sweep extra: {EXTRA})") from None
    return netCDF4


class FieldsWriter(Writer):
    """The fields of a :class:`Grid` of bin size ``bin_size`` every ``every`` steps (from
    the run's origin; the first and last step too) into the netCDF file ``path``, a frame
    at a time along an unlimited ``time`` dimension (``mode="a"`` appends to a file a run
    wrote, skipping steps it holds). The file is synced at every :meth:`sync` (before each
    checkpoint) and closed at the end. Missing netCDF4 is refused when the writer is made.
    """

    def __init__(self, path: str | os.PathLike, bin_size: float, every: int = 100, mode: str = "w"):
        self._nc = require_netcdf()
        self.path = os.fspath(path)
        self.bin_size = bin_size
        self.every = int(every)
        self.mode = mode
        self.grid: Grid | None = None
        self._file = None
        self._last = None

    def begin(self, sim) -> None:
        if self._file is not None:
            return
        self.grid = Grid.of(sim.model, self.bin_size)
        if self.mode == "a" and os.path.exists(self.path):
            self._file = self._nc.Dataset(self.path, "a")
            steps = self._file["step"][:]
            self._last = int(steps[-1]) if len(steps) else None
        else:
            self._file = self._nc.Dataset(self.path, "w", format="NETCDF4")
            describe(self._file, self.grid, sim)
        self.mode = "a"

    def write(self, sim) -> None:
        if self._last is not None and sim.step <= self._last:
            return
        grid, f = self.grid, self._file
        sums = sim.backend.fields(grid)
        t = len(f.dimensions["time"])
        f["step"][t] = sim.step
        f["time"][t] = sim.step * sim.model.dt
        shape = grid.frame_shape()
        for name, data in channels(grid, sums).items():
            f[name][t] = data.reshape(shape)
        self._last = sim.step

    def sync(self) -> None:
        if self._file is not None:
            self._file.sync()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def channels(grid: Grid, sums: np.ndarray) -> dict[str, np.ndarray]:
    """The file's variables of one frame from sums ``(species, channel, bin)``: the totals
    over species under the channels' names, then (several species) each species' with
    ``_<name>`` appended. Counts as whole numbers (int64)."""
    names = grid.names()
    total = sums.sum(axis=0)
    out = {}
    for c, name in enumerate(names):
        out[name] = np.rint(total[c]).astype(np.int64) if c == 0 else total[c]
    if grid.species > 1:
        for s, species in enumerate(grid.species_names):
            for c, name in enumerate(names):
                out[f"{name}_{species}"] = np.rint(sums[s, c]).astype(np.int64) if c == 0 else sums[s, c]
    return out


def long_names(grid: Grid) -> dict[str, str]:
    """Each variable of a frame (:func:`channels`' names) and what it holds."""
    texts = {"count": "particles in the bin"}
    texts.update({f"polarisation_{a}": f"sum of the unit headings' {a} component" for a in "xyz"[: grid.dim]})
    texts.update({name: f"sum of the nematic product {name[8:]} (flocking.observables.moment_sums)"
                  for name in grid.names() if name.startswith("nematic_")})
    out = dict(texts)
    if grid.species > 1:
        for species in grid.species_names:
            out.update({f"{name}_{species}": f"{text}, species {species}" for name, text in texts.items()})
    return out


def describe(f, grid: Grid, sim) -> None:
    """Dimensions, coordinates (bin centres), variables and attributes of a new file."""
    axes = "xyz"[: grid.dim]
    f.createDimension("time", None)
    for a in reversed(range(grid.dim)):
        f.createDimension(axes[a], grid.shape[a])
    step = f.createVariable("step", "i8", ("time",))
    step.long_name = "step of the run"
    time = f.createVariable("time", "f8", ("time",))
    time.long_name, time.units = "time (step x dt)", "model time"
    for a in range(grid.dim):
        v = f.createVariable(axes[a], "f8", (axes[a],))
        v[:] = (np.arange(grid.shape[a]) + 0.5) * grid.widths[a]
        v.long_name, v.units = f"bin centre along {axes[a]} (box coordinates, 0 to L)", "length"
    dims = ("time", *reversed(axes))
    for name, text in long_names(grid).items():
        v = f.createVariable(name, "i8" if name.startswith("count") else "f8", dims, zlib=True, complevel=1,
                             chunksizes=(1, *grid.frame_shape()))
        v.long_name = text
    f.title = "flocking coarse-grained fields"
    f.bin_widths = np.array(grid.widths)
    f.box = np.array(grid.box)
    f.species = json.dumps(list(grid.species_names))
    f.parameters = json.dumps(sim.parameters())


def open(path: str | os.PathLike):  # noqa: A001 - as flocking.open for trajectories
    """A fields file as an ``xarray.Dataset`` (the sweep extra), loaded into memory."""
    try:
        import xarray
    except ImportError:
        raise ParameterError(f"fields: reading fields needs xarray (the sweep extra: {EXTRA})") from None
    try:
        with xarray.open_dataset(os.fspath(path)) as ds:
            return ds.load()
    except (OSError, ValueError) as err:
        raise ParameterError(f"fields: cannot read {os.fspath(path)!r} ({err})") from None


def rewind(path: str, step: int) -> None:
    """Drop the frames after ``step`` (before a resume continues the run), rewriting the
    file beside itself and renaming it over the old one."""
    nc = require_netcdf()
    with nc.Dataset(path, "r") as src:
        steps = src["step"][:]
        keep = int(np.count_nonzero(np.asarray(steps) <= step))
        if keep == len(steps):
            return
        tmp = path + ".tmp"
        with nc.Dataset(tmp, "w", format="NETCDF4") as dst:
            dst.setncatts({k: src.getncattr(k) for k in src.ncattrs()})
            for name, dim in src.dimensions.items():
                dst.createDimension(name, None if dim.isunlimited() else len(dim))
            for name, var in src.variables.items():
                opts = var.filters() or {}
                out = dst.createVariable(name, var.dtype, var.dimensions, zlib=bool(opts.get("zlib")),
                                         chunksizes=var.chunking() if var.chunking() != "contiguous" else None)
                out.setncatts({k: var.getncattr(k) for k in var.ncattrs()})
                out[:] = var[:keep] if "time" in var.dimensions else var[:]
    os.replace(tmp, path)
