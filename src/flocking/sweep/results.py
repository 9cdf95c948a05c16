"""A sweep's results as an xarray Dataset: gather, save (netCDF or Zarr), open.

Dimensions: the swept parameters, in the order of the sweep file, then ``replica``.
Variables, one value per run (NaN where a run failed or has not run yet):

- ``order`` (the time average of the polar order ``<phi>``), ``phi2``, ``phi4``,
  ``susceptibility`` (``N (<phi^2> - <phi>^2)``), ``binder`` (``1 - <phi^4> / 3 <phi^2>^2``),
  all over the steps after the transient (``flocking.observables.polar_moments``);
- ``order_error``, ``phi2_error``, ... ``binder_error``: their errors within the run
  (:class:`flocking.analysis.PolarOrder`: the integrated autocorrelation time for
  ``<phi>``, a block jackknife for the others), ``tau`` (that autocorrelation time, in
  steps) and ``drift`` (the difference of the two halves of the window in errors; above 4
  the run had likely not settled);
- ``seed`` (the run's seed), ``n`` (its particle count), ``status`` (``done``, ``failed``
  or ``missing``), ``config`` (the run's TOML configuration: ``flocking run --config``
  repeats it), ``elapsed`` (seconds; the one variable that differs between two runs of a sweep);
- with ``time_series = true``: ``phi`` over an extra dimension ``sample`` (the measured
  steps, ``first_step`` onward; NaN-padded where runs have different lengths);
- where the models have them (:func:`flocking.observables.extra_names`): the time average
  of each species' polar order ``polar_order_<name>`` (several species) and of the nematic
  order ``nematic_order`` (``alignment_rule = "nematic"``) over the same steps, each with
  its ``..._error`` from its autocorrelation time; NaN at the points whose model has not.

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

#: Result variable -> the moment of a record it holds.
MEASURES = {"order": "mean", "phi2": "phi2", "phi4": "phi4", "susceptibility": "susceptibility",
            "binder": "binder"}
_LONG_NAMES = {"order": "<phi>", "phi2": "<phi^2>", "phi4": "<phi^4>",
               "susceptibility": "N (<phi^2> - <phi>^2)", "binder": "1 - <phi^4> / (3 <phi^2>^2)"}


def gather(spec: SweepSpec, out: str | os.PathLike):
    """The Dataset of every point of ``spec`` stored under ``out``.

    Records stored by a flocking older than within-run errors hold NaN errors.
    """
    import xarray as xr

    store = PointStore(out)
    shape = spec.shape
    errors = [f"{name}_error" for name in MEASURES]
    floats = {name: np.full(shape, np.nan) for name in (*MEASURES, *errors, "tau", "drift", "elapsed")}
    seed = np.zeros(shape, dtype=np.int64)
    size = np.zeros(shape, dtype=np.int64)
    first = np.zeros(shape, dtype=np.int64)
    status = np.full(shape, "missing", dtype=object)
    config = np.full(shape, "", dtype=object)
    series = {}
    extra: dict[str, np.ndarray] = {}
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
        within = record.get("errors", {})
        for name, moment in MEASURES.items():
            floats[name][i] = record["moments"][moment]
            floats[f"{name}_error"][i] = _number(within.get(moment))
        floats["tau"][i], floats["drift"][i] = _number(record.get("tau")), _number(record.get("drift"))
        first[i] = record["first_step"]
        for name, value in record.get("extra", {}).items():
            for column, number in ((name, value["mean"]), (f"{name}_error", value["error"])):
                extra.setdefault(column, np.full(shape, np.nan))[i] = _number(number)
        if "phi" in record:
            series[i] = record["phi"]
    dims = spec.dims
    coords = {key: _coordinate(values) for key, values in spec.grid.items()}
    coords["replica"] = np.arange(spec.replicas)
    data = {name: (dims, values) for name, values in floats.items()}
    data.update({name: (dims, values) for name, values in extra.items()})  # in the records' order
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
    for name, text in _LONG_NAMES.items():
        ds[name].attrs["long_name"] = text
        ds[f"{name}_error"].attrs["long_name"] = f"error of {text} within the run"
    ds["tau"].attrs["long_name"] = "integrated autocorrelation time of phi"
    ds["tau"].attrs["units"] = "steps"
    ds["drift"].attrs["long_name"] = "second-half mean - first-half mean of phi, in errors"
    for name in extra:
        base = name.removesuffix("_error")
        text = "nematic order" if base == "nematic_order" else f"polar order of species {base[len('polar_order_'):]}"
        ds[name].attrs["long_name"] = (f"error of <{text}> within the run" if name.endswith("_error")
                                       else f"<{text}>")
    return ds


def _number(value) -> float:
    return np.nan if value is None else float(value)


def _coordinate(values: list[Any]) -> np.ndarray:
    """Numbers and strings stay as they are; anything else (a box per axis) becomes text."""
    if all(isinstance(v, (int, float, str)) and not isinstance(v, bool) for v in values):
        return np.asarray(values)
    return np.asarray([json.dumps(v) for v in values])


def save(ds, path: str | os.PathLike) -> str:
    """Write ``ds`` to ``path`` (``.nc``: netCDF4, ``.zarr``: Zarr), replacing it atomically.

    Zarr stores are written in Zarr format 2 with consolidated metadata: its text type
    (``<U``) and its consolidated metadata are part of that specification, so every Zarr
    reader (zarr-python 2 and 3 among them) and ``xarray.open_zarr`` read it without a
    warning, which format 3 does not allow yet (no specified fixed-length text type, and
    consolidated metadata outside its specification).
    """
    path = os.fspath(path)
    check_results_path(path)
    tmp = f"{path}.tmp{os.getpid()}"
    if path.endswith(".nc"):
        ds.to_netcdf(tmp, engine="netcdf4")
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        return path
    import zarr

    shutil.rmtree(tmp, ignore_errors=True)
    version = {"zarr_format": 2} if int(zarr.__version__.split(".")[0]) >= 3 else {}
    ds.to_zarr(tmp, mode="w", consolidated=True, **version)
    old = f"{path}.old{os.getpid()}"
    if os.path.isdir(path):
        os.replace(path, old)  # a folder cannot be renamed over another: move the old one aside
    os.replace(tmp, path)
    shutil.rmtree(old, ignore_errors=True)
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
        opened = xr.open_zarr(path) if path.rstrip("/").endswith(".zarr") else xr.open_dataset(path)
        with opened as ds:
            return ds.load()
    except Exception as err:  # netCDF and Zarr raise many kinds on a foreign file
        raise ParameterError(f"results: cannot read {path!r} ({err})") from None
