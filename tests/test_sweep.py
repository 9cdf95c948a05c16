"""Sweeps: the sweep file, the point store and resumption, Dask against serial, results, CLI."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

xr = pytest.importorskip("xarray")
distributed = pytest.importorskip("distributed")

import flocking  # noqa: E402
from flocking.cli import main  # noqa: E402
from flocking.model import ParameterError  # noqa: E402
from flocking.observables import polar_moments  # noqa: E402
from flocking.sweep import require  # noqa: E402
from flocking.sweep.figures import summarise  # noqa: E402
from flocking.sweep.results import gather, open_results, save  # noqa: E402
from flocking.sweep.executors import Dask, Serial  # noqa: E402
from flocking.sweep.point import run_point  # noqa: E402
from flocking.sweep.runner import PointStore, execute, task_of  # noqa: E402
from flocking.sweep.spec import SweepSpec, expand, point_seed  # noqa: E402

SRC = os.path.join(os.path.dirname(__file__), os.pardir, "src")

SMALL = """
[sweep]
seed = 7
replicas = 2
discard = 0.5

[base]
density = 2.0
steps = 40

[grid]
noise = [0.5, 3.0, 6.0]
n = [20, 40]
"""


def spec_of(**tables):
    return SweepSpec.from_dict(tables)


@pytest.fixture(scope="module")
def cluster():
    """A real Dask cluster on loopback: one single-threaded worker inside this process."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address="127.0.0.1:0") as c:
        yield c


def on(cluster):
    """An executor on the running ``cluster`` (as ``--scheduler`` makes one)."""
    return Dask(scheduler=cluster.scheduler_address, report=lambda text: None)


def results_without_timing(out):
    return open_results(os.path.join(out, "results.nc")).drop_vars("elapsed")


def run_and_save(spec, out, executor=None):
    summary = execute(spec, out, executor, progress=False, report=lambda text: None)
    save(gather(spec, out), os.path.join(out, "results.nc"))
    return summary


# -- the sweep file -------------------------------------------------------------------------------

def test_points_are_the_product_of_the_grid_times_replicas():
    spec = SweepSpec.from_toml(SMALL)
    points = spec.points()
    assert spec.dims == ("noise", "n", "replica") and spec.shape == (3, 2, 2)
    assert len(points) == 12 and len({p.id for p in points}) == 12
    assert [p.index for p in points[:3]] == [(0, 0, 0), (0, 0, 1), (0, 1, 0)]
    p = points[5]  # noise 3.0, n 20, replica 1
    assert p.params == {"noise": 3.0, "n": 20} and p.replica == 1
    assert p.config.model.noise == 3.0 and p.config.model.n == 20 and p.config.steps == 40
    assert p.discard == 20


def test_point_seed_depends_only_on_sweep_seed_point_and_replica():
    a = SweepSpec.from_toml(SMALL).points()
    b = spec_of(sweep={"seed": 7, "replicas": 3}, base={"density": 2.0, "steps": 99},
                grid={"n": [40, 20, 80], "noise": [6.0, 0.5]}).points()
    seeds_b = {(tuple(sorted(p.params.items())), p.replica): p.config.model.seed for p in b}
    for p in a:
        key = (tuple(sorted(p.params.items())), p.replica)
        if key in seeds_b:
            assert p.config.model.seed == seeds_b[key] == point_seed(7, p.params, p.replica)
    seeds = [p.config.model.seed for p in a]
    assert len(set(seeds)) == len(seeds) and all(0 <= s < 2**53 for s in seeds)
    assert point_seed(8, a[0].params, 0) != point_seed(7, a[0].params, 0)


def test_ranges_expand_inclusively_and_round_integer_parameters():
    assert expand("noise", {"start": 0.0, "stop": 1.0, "num": 5}) == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert expand("n", {"start": 100, "stop": 10000, "num": 3, "scale": "log"}) == [100, 1000, 10000]
    assert expand("noise", {"start": 2, "stop": 9, "num": 1}) == [2.0]
    assert expand("noise", [1, 2.5]) == [1.0, 2.5]


@pytest.mark.parametrize("tables, message", [
    ({"sweeep": {}}, "sweeep: unknown parameter; did you mean 'sweep'?"),
    ({"sweep": {"replica": 2}}, "sweep.replica: unknown parameter; did you mean 'replicas'?"),
    ({"base": {"nois": 1.0}}, "base.nois: unknown parameter; did you mean 'noise'?"),
    ({"grid": {"densty": [1.0]}}, "grid.densty: unknown parameter; did you mean 'density'?"),
    ({"base": {"seed": 1}}, "base.seed: each run's seed derives from the sweep seed"),
    ({"grid": {"seed": [1, 2]}}, "grid.seed: each run's seed derives from the sweep seed"),
    ({"base": {"noise": 1.0}, "grid": {"noise": [1.0]}}, "grid.noise: also set in [base]"),
    ({"grid": {"noise": 1.0}}, "grid.noise: must be a list of values or a range"),
    ({"grid": {"noise": []}}, "grid.noise: must hold at least one value"),
    ({"grid": {"noise": [1.0, 1.0]}}, "grid.noise: values must differ"),
    ({"grid": {"noise": {"start": 0, "stop": 1}}}, "grid.noise: a range needs start, stop and num (missing num)"),
    ({"grid": {"noise": {"start": 0, "stop": 1, "num": 2, "step": 1}}}, "grid.noise.step: unknown parameter"),
    ({"grid": {"noise": {"start": 0, "stop": 1, "num": 2, "scale": "log"}}}, "grid.noise: a log range needs"),
    ({"grid": {"noise": [1.0, 7.0]}}, "grid point {noise = 7.0}: noise: must be in [0, 2*pi]"),
    ({"base": {"box": 4.0, "density": 2.0}, "grid": {"n": [10]}}, "grid point {n = 10}: n, density, box"),
    ({"sweep": {"replicas": 0}}, "sweep.replicas: must be a whole number >= 1"),
    ({"sweep": {"discard": 1.0}}, "sweep.discard: a fraction must be in [0, 1)"),
    ({"sweep": {"discard": "half"}}, "sweep.discard: must be a number of steps"),
    ({"sweep": {"discard": 49}, "base": {"steps": 50}}, "sweep.discard: must leave at least two steps"),
    ({"sweep": {"time_series": 1}}, "sweep.time_series: must be true or false"),
    ({"base": []}, "base: must be a table"),
])
def test_bad_sweep_files_are_refused_naming_the_key(tables, message):
    with pytest.raises(ParameterError) as err:
        SweepSpec.from_dict(tables)
    assert message in str(err.value)


# -- running points -------------------------------------------------------------------------------

def test_a_point_measures_the_polar_order_of_its_own_run(tmp_path):
    spec = SweepSpec.from_toml(SMALL)
    point = spec.points()[3]
    record = run_point(task_of(point, str(tmp_path), spec, threads=None))
    assert record["status"] == "done" and record["seed"] == point.config.model.seed
    sim = flocking.Simulation(point.config.model)
    sim.run(point.config.steps)
    assert record["moments"] == polar_moments(sim.polar_order[21:], point.config.model.n)
    assert record["first_step"] == 21


def test_serial_and_dask_give_identical_results_and_a_rerun_computes_nothing(tmp_path, cluster):
    spec = SweepSpec.from_toml(SMALL)
    serial, dask = str(tmp_path / "serial"), str(tmp_path / "dask")
    s = run_and_save(spec, serial, Serial())
    d = run_and_save(spec, dask, on(cluster))
    assert (s["done"], s["failed"], d["done"], d["failed"]) == (12, 0, 12, 0)
    a, b = results_without_timing(serial), results_without_timing(dask)
    xr.testing.assert_identical(a, b)
    assert a["order"].dims == ("noise", "n", "replica") and a["order"].shape == (3, 2, 2)
    assert (a["status"] == "done").all() and np.isfinite(a["order"]).all()
    # ordered at low noise, disordered at eta = 6 (of 2 pi): phi ~ 1/sqrt(N) there
    assert (a["order"].sel(noise=0.5) > 0.9).all() and (a["order"].sel(noise=6.0) < 0.5).all()
    chi = (a["n"] * (a["phi2"] - a["order"] ** 2)).transpose(*a["order"].dims)
    assert np.allclose(a["susceptibility"], chi, rtol=1e-9, atol=1e-12)
    config = flocking.config.RunConfig.from_toml(str(a["config"].sel(noise=3.0, n=40, replica=1).values))
    assert config.model.seed == int(a["seed"].sel(noise=3.0, n=40, replica=1))
    again = execute(spec, dask, on(cluster), progress=False)
    assert (again["done"], again["skipped"]) == (0, 12)


def test_resume_computes_only_the_missing_points_and_matches_an_uninterrupted_sweep(tmp_path, cluster):
    spec = SweepSpec.from_toml(SMALL)
    out = str(tmp_path / "out")
    run_and_save(spec, out)
    whole = results_without_timing(out)
    store = PointStore(out)
    lost = [p.id for p in spec.points()[4:7]]
    for point_id in lost:
        os.remove(store.path(point_id))
    with open(store.path(spec.points()[0].id), "w") as f:
        f.write('{"id": "trunc')  # a torn file (not ours: we write atomically) counts as missing
    summary = run_and_save(spec, out, on(cluster))
    assert (summary["done"], summary["skipped"]) == (4, 8)
    xr.testing.assert_identical(results_without_timing(out), whole)


def test_a_failing_point_is_recorded_does_not_stop_the_others_and_is_retried(tmp_path, cluster):
    bad = tmp_path / "start.gsd"
    bad.write_bytes(b"not a gsd file")
    spec = spec_of(sweep={"replicas": 1, "discard": 5}, base={"n": 30, "box": 5.0, "steps": 10},
                   grid={"noise": [0.5, 2.0], "init": ["random", str(bad)]})
    out = str(tmp_path / "out")
    messages = []
    summary = execute(spec, out, on(cluster), progress=False, report=messages.append)
    assert (summary["done"], summary["failed"]) == (2, 2)
    assert len(messages) == 2 and all("failed" in m and f"init='{bad}'" in m and "noise=" in m for m in messages)
    ds = gather(spec, out)
    assert list(ds["status"].sel(init=str(bad)).values.ravel()) == ["failed", "failed"]
    assert np.isnan(ds["order"].sel(init=str(bad))).all() and np.isfinite(ds["order"].sel(init="random")).all()
    record = PointStore(out).load(spec.points()[1].id)
    assert record["status"] == "failed" and "init: cannot read a frame" in record["error"]
    # repair the input: the next run retries the failed points only
    sim = flocking.Simulation(spec.points()[0].config.model)
    sim.writers.append(flocking.GSDWriter(str(bad), every=0))
    sim.run(3)
    again = execute(spec, out, progress=False)
    assert (again["done"], again["failed"], again["skipped"]) == (2, 0, 2)
    assert (gather(spec, out)["status"] == "done").all()


def test_killing_a_sweep_keeps_every_finished_point_and_the_rerun_completes_it(tmp_path):
    text = SMALL.replace("steps = 40", "steps = 3000").replace("n = [20, 40]", "n = [200, 400]")
    (tmp_path / "s.toml").write_text(text)
    env = {**os.environ, "PYTHONPATH": os.path.abspath(SRC), "NUMBA_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "flocking", "sweep", "s.toml", "--serial", "-q"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env)
    points = tmp_path / "s" / "points"
    deadline = time.time() + 180  # generous: a shared machine may run it slowly
    while time.time() < deadline and len(list(points.glob("*.json"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    stored = list(points.glob("*.json"))
    assert 2 <= len(stored) < 12
    assert all(json.loads(p.read_text())["status"] == "done" for p in stored)
    done = subprocess.run(cmd[:-1], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert f"{12 - len(stored)} run, 0 failed, {len(stored)} already stored" in done.stderr
    ds = open_results(str(tmp_path / "s"))
    assert (ds["status"] == "done").all()


# -- results --------------------------------------------------------------------------------------

def test_time_series_trajectories_and_zarr(tmp_path):
    spec = spec_of(sweep={"replicas": 1, "discard": 4, "time_series": True, "keep_trajectories": True},
                   base={"n": 25, "box": 5.0, "steps": 10, "every": 5}, grid={"noise": [0.5, 1.5]})
    out = str(tmp_path / "out")
    execute(spec, out, progress=False)
    ds = gather(spec, out)
    assert ds["phi"].shape == (2, 1, 6) and (ds["first_step"] == 5).all()
    for point in spec.points():
        phi = ds["phi"].sel(noise=point.params["noise"], replica=0).values
        assert float(ds["order"].sel(noise=point.params["noise"], replica=0)) == polar_moments(phi, 25)["mean"]
        with flocking.open(os.path.join(out, "points", point.id, "trajectory.gsd")) as traj:
            assert [f.step for f in traj] == [0, 5, 10] and traj.model.seed == point.config.model.seed
            assert traj[-1].polar_order == pytest.approx(phi[-1], abs=1e-6)  # float32 frames
    save(ds, str(tmp_path / "r.zarr"))
    xr.testing.assert_identical(open_results(str(tmp_path / "r.zarr")), ds)
    with pytest.raises(ParameterError, match="must end in .nc"):
        save(ds, str(tmp_path / "r.csv"))


def test_results_files_are_written_and_read_without_any_warning(tmp_path):
    """netCDF and Zarr, text (status, configurations, a text coordinate), NaN (a missing
    run) and a time series: written twice (the second replaces the first) and read by
    every reader at hand, with every warning an error."""
    import netCDF4
    zarr = pytest.importorskip("zarr")

    spec = spec_of(sweep={"replicas": 2, "discard": 4, "time_series": True}, base={"n": 25, "box": 5.0, "steps": 10},
                   grid={"noise": [0.5, 1.5], "init": ["random", "aligned"]})
    out = str(tmp_path / "out")
    execute(spec, out, progress=False)
    os.remove(PointStore(out).path(spec.points()[-1].id))
    ds = gather(spec, out)
    assert ds["status"].values.ravel().tolist().count("missing") == 1 and np.isnan(ds["order"]).sum() == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("r.nc", "r.zarr"):
            path = str(tmp_path / name)
            save(ds.isel(replica=[0]), path)
            save(ds, path)
            xr.testing.assert_identical(open_results(path), ds)
            assert sorted(os.listdir(tmp_path)) == sorted(["out", *(["r.nc"] if name == "r.zarr" else []), name])
        with xr.open_zarr(str(tmp_path / "r.zarr")) as z:
            xr.testing.assert_identical(z.load(), ds)
        with xr.open_dataset(str(tmp_path / "r.zarr"), engine="zarr") as z:
            xr.testing.assert_identical(z.load(), ds)
        group = zarr.open_group(str(tmp_path / "r.zarr"), mode="r")
        assert group["status"][...].tolist() == ds["status"].values.tolist()
        assert np.array_equal(group["order"][...], ds["order"].values, equal_nan=True)
        with xr.open_dataset(str(tmp_path / "r.nc"), engine="netcdf4") as nc:
            xr.testing.assert_identical(nc.load(), ds)
        with netCDF4.Dataset(str(tmp_path / "r.nc")) as nc:
            assert np.array_equal(nc["phi"][...].filled(np.nan), ds["phi"].values, equal_nan=True)
            assert nc["config"][0, 0, 0] == ds["config"].values[0, 0, 0]


def test_results_without_within_run_errors_are_summarised_with_standard_errors():
    """A results file of an older flocking: no ``*_error`` variables."""
    order = np.array([[[0.2, 0.4, 0.6], [0.5, 0.5, np.nan]]])  # noise x n x replica
    ds = xr.Dataset({name: (("noise", "n", "replica"), order) for name in ("order", "susceptibility", "binder")},
                    coords={"noise": [1.0], "n": [10, 20], "replica": [0, 1, 2]})
    x, curves, stats = summarise(ds)
    assert (x, curves) == ("noise", ["n"])
    mean, sem = stats["order"]
    assert np.allclose(mean.values, [[0.4, 0.5]])
    assert np.allclose(sem.values, [[0.2 / np.sqrt(3), 0.0]])
    with pytest.raises(ParameterError, match="x: must be one of the swept parameters noise, n"):
        summarise(ds, x="speed")


def test_a_missing_extra_names_the_install_command():
    with pytest.raises(ParameterError, match=r"pip install '\.\[sweep\]' in flocking's source folder"):
        require("flocking_no_such_module")


# -- command line ---------------------------------------------------------------------------------

def test_cli_sweep_then_plot(tmp_path):
    from click.testing import CliRunner

    (tmp_path / "g.toml").write_text(SMALL)
    runner = CliRunner()
    with contextlib.chdir(tmp_path):
        result = runner.invoke(main, ["sweep", "g.toml", "--serial", "-q", "--results", "g.zarr"])
        assert result.exit_code == 0, result.output
        assert os.path.isdir("g/points") and os.path.isdir("g.zarr") and not os.path.exists("g/results.nc")
        result = runner.invoke(main, ["plot-sweep", "g.zarr", "--out", "fig.png"])
        assert result.exit_code == 0, result.output
        with open("fig.png", "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, text", [
    (["sweep", "bad.toml"], "grid.nosie: unknown parameter; did you mean 'noise'?"),
    (["sweep", "missing.toml"], "sweep: cannot read 'missing.toml'"),
    (["sweep", "good.toml", "--serial", "--workers", "2"], "--serial: runs in this process"),
    (["sweep", "good.toml", "--results", "r.txt"], "--results: must end in .nc"),
    (["plot-sweep", "nothing.nc"], "Error: results: no such file"),
])
def test_cli_errors_are_one_line_and_nothing_is_written(tmp_path, args, text):
    from click.testing import CliRunner

    runner = CliRunner()
    with contextlib.chdir(tmp_path):
        with open("bad.toml", "w") as f:
            f.write("[grid]\nnosie = [1.0]\n")
        with open("good.toml", "w") as f:
            f.write(SMALL)
        result = runner.invoke(main, args)
        assert result.exit_code == 2
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("Error: ") and text in lines[0]
        assert sorted(os.listdir(".")) == ["bad.toml", "good.toml"]
