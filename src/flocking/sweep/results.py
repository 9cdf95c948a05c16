"""A sweep's results as an xarray Dataset: gather, save (netCDF or Zarr), open, plot.

Dimensions: the swept parameters, in the order of the sweep file, then ``replica``.
Variables, one value per run (NaN where a run failed or has not run yet):

- ``order`` (the time average of the polar order ``<phi>``), ``phi2``, ``phi4``,
  ``susceptibility`` (``N (<phi^2> - <phi>^2)``), ``binder`` (``1 - <phi^4> / 3 <phi^2>^2``),
  all over the steps after the transient (``flocking.observables.polar_moments``);
- ``seed`` (the run's seed), ``n`` (its particle count), ``status`` (``done``, ``failed``
  or ``missing``), ``config`` (the run's TOML configuration: ``flocking run --config``
  repeats it), ``elapsed`` (seconds; the one variable that differs between two runs of a sweep);
- with ``time_series = true``: ``phi`` over an extra dimension ``sample`` (the measured
  steps, ``first_step`` onward; NaN-padded where runs have different lengths).

The attributes hold the sweep file (``sweep``), its seed, replicas and transient.
"""

from __future__ import annotations

import json
import os
import shutil
from typing import Any

import numpy as np

from ..model import ParameterError
from .runner import PointStore
from .spec import SweepSpec

MEASURES = ("order", "phi2", "phi4", "susceptibility", "binder")
_MOMENT = {"order": "mean", "phi2": "phi2", "phi4": "phi4", "susceptibility": "susceptibility",
           "binder": "binder"}
#: Parameters that set the system size: one curve each in ``plot-sweep``.
SIZE_KEYS = ("n", "box", "density")


def gather(spec: SweepSpec, out: str | os.PathLike):
    """The Dataset of every point of ``spec`` stored under ``out``."""
    import xarray as xr

    store = PointStore(out)
    shape = spec.shape
    floats = {name: np.full(shape, np.nan) for name in (*MEASURES, "elapsed")}
    seed = np.zeros(shape, dtype=np.int64)
    size = np.zeros(shape, dtype=np.int64)
    first = np.zeros(shape, dtype=np.int64)
    status = np.full(shape, "missing", dtype=object)
    config = np.full(shape, "", dtype=object)
    series = {}
    for point in spec.points():
        i = point.index
        seed[i], size[i] = point.config.model.seed, point.config.model.n
        config[i] = point.config.to_toml()
        record = store.load(point.id)
        if record is None:
            continue
        status[i] = record["status"]
        floats["elapsed"][i] = record.get("elapsed", np.nan)
        if record["status"] != "done":
            continue
        for name in MEASURES:
            floats[name][i] = record["moments"][_MOMENT[name]]
        first[i] = record["first_step"]
        if "phi" in record:
            series[i] = record["phi"]
    dims = spec.dims
    coords = {key: _coordinate(values) for key, values in spec.grid.items()}
    coords["replica"] = np.arange(spec.replicas)
    data = {name: (dims, floats[name]) for name in (*MEASURES, "elapsed")}
    data.update(seed=(dims, seed), n=(dims, size), status=(dims, status.astype(str)),
                config=(dims, config.astype(str)))
    if spec.time_series:
        length = max((len(s) for s in series.values()), default=0)
        phi = np.full((*shape, length), np.nan)
        for i, s in series.items():
            phi[i][: len(s)] = s
        data["phi"] = ((*dims, "sample"), phi)
        data["first_step"] = (dims, first)
    if "n" in spec.grid:  # the particle count is a coordinate already
        data.pop("n")
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(sweep=spec.text, sweep_seed=spec.seed, replicas=spec.replicas,
                    discard=json.dumps(spec.discard), title="flocking sweep",
                    seed_rule="sha256(json {point, replica, seed}) first 8 bytes little-endian >> 11")
    units = {"order": "<phi>", "phi2": "<phi^2>", "phi4": "<phi^4>",
             "susceptibility": "N (<phi^2> - <phi>^2)", "binder": "1 - <phi^4> / (3 <phi^2>^2)"}
    for name, text in units.items():
        ds[name].attrs["long_name"] = text
    return ds


def _coordinate(values: list[Any]) -> np.ndarray:
    """Numbers and strings stay as they are; anything else (a box per axis) becomes text."""
    if all(isinstance(v, (int, float, str)) and not isinstance(v, bool) for v in values):
        return np.asarray(values)
    return np.asarray([json.dumps(v) for v in values])


def save(ds, path: str | os.PathLike) -> str:
    """Write ``ds`` to ``path`` (``.nc``: netCDF4, ``.zarr``: Zarr), replacing it atomically."""
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}"
    if path.endswith(".nc"):
        ds.to_netcdf(tmp, engine="netcdf4")
        os.replace(tmp, path)
    elif path.endswith(".zarr"):
        shutil.rmtree(tmp, ignore_errors=True)
        ds.to_zarr(tmp, mode="w")
        if os.path.isdir(path):
            shutil.rmtree(path)
        os.replace(tmp, path)
    else:
        raise ParameterError(f"results: must end in .nc (netCDF) or .zarr (got {path!r})")
    return path


def check_results_path(path: str) -> None:
    """Refuse a results path with an unknown extension, before any work."""
    if not (path.endswith(".nc") or path.endswith(".zarr")):
        raise ParameterError(f"results: must end in .nc (netCDF) or .zarr (got {path!r})")


def open_results(path: str | os.PathLike):
    """A results file (``.nc`` or ``.zarr``), or a sweep folder holding ``results.nc``, loaded."""
    import xarray as xr

    path = os.fspath(path)
    if os.path.isdir(path) and not path.rstrip("/").endswith(".zarr"):
        inner = [os.path.join(path, name) for name in ("results.nc", "results.zarr")]
        found = [p for p in inner if os.path.exists(p)]
        if not found:
            raise ParameterError(f"results: {path!r} holds no results.nc or results.zarr")
        path = found[0]
    if not os.path.exists(path):
        raise ParameterError(f"results: no such file {path!r}")
    try:
        if path.rstrip("/").endswith(".zarr"):
            ds = xr.open_zarr(path)
        else:
            ds = xr.open_dataset(path)
        return ds.load()
    except Exception as err:  # netCDF and Zarr raise many kinds on a foreign file
        raise ParameterError(f"results: cannot read {path!r} ({err})") from None


def summarise(ds, x: str | None = None):
    """Mean and standard error over replicas of each measure, and the axis and curve dimensions.

    ``x`` defaults to the first swept parameter that does not set the system size; curves
    are every combination of the other swept parameters.
    """
    dims = [d for d in ds["order"].dims if d != "replica"]
    if not dims:
        raise ParameterError("results: nothing was swept; there is no curve to draw")
    if x is None:
        others = [d for d in dims if d not in SIZE_KEYS]
        x = (others or dims)[0]
    elif x not in dims:
        raise ParameterError(f"x: must be one of the swept parameters {', '.join(dims)} (got {x!r})")
    curves = [d for d in dims if d != x]
    stats = {}
    for name in ("order", "susceptibility", "binder"):
        values = ds[name]
        count = values.count("replica")
        mean = values.mean("replica", skipna=True)
        sem = values.std("replica", ddof=1, skipna=True) / np.sqrt(count)
        stats[name] = (mean, sem.where(count > 1, 0.0))
    return x, curves, stats


def plot(ds, path: str | os.PathLike, x: str | None = None) -> str:
    """Order, susceptibility and Binder cumulant against ``x``, one curve per other setting, as PNG."""
    import itertools

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, curves, stats = summarise(ds, x)
    labels = {"order": r"order $\langle\phi\rangle$", "susceptibility": r"susceptibility $\chi$",
              "binder": r"Binder cumulant $G$"}
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    combos = list(itertools.product(*(range(ds.sizes[c]) for c in curves)))
    for combo in combos:
        sel = {c: i for c, i in zip(curves, combo)}
        label = ", ".join(f"{c}={ds[c].values[i]}" for c, i in sel.items()) or None
        for ax, name in zip(axes, stats):
            mean, sem = (a.isel(sel) for a in stats[name])
            ax.errorbar(ds[x].values, mean.values, yerr=sem.values, marker="o", ms=3.5, capsize=2,
                        lw=1.2, label=label)
    for ax, name in zip(axes, stats):
        ax.set_xlabel(x)
        ax.set_ylabel(labels[name])
        ax.grid(alpha=0.3)
    axes[0].set_ylim(bottom=0)
    axes[2].axhline(2 / 3, color="0.6", ls="--", lw=0.8)
    axes[2].axhline(1 / 3, color="0.6", ls=":", lw=0.8)
    if combos and curves:
        axes[0].legend(fontsize=8)
    title = ds.attrs.get("title", "")
    reps = ds.sizes.get("replica", 1)
    fig.suptitle(f"{title}: mean over {reps} replica{'s' * (reps != 1)}, error bars: standard error",
                 fontsize=10)
    path = os.fspath(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
