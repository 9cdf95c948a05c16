"""``flocking sweep`` and ``flocking plot-sweep``: phase diagrams from one sweep file."""

from __future__ import annotations

import os
import sys
import time

import click

from ..model import ParameterError


@click.command()
@click.argument("sweep_file", metavar="SWEEP.toml", type=click.Path(dir_okay=False))
@click.option("--out", default=None, help="Output folder. [default: the sweep file's name, here]")
@click.option("--results", default=None,
              help="Results file, .nc (netCDF) or .zarr. [default: OUT/results.nc]")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Address of a running Dask scheduler, e.g. tcp://10.0.0.1:8786. [default: a local cluster]")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Worker processes of the local cluster. [default: one per core]")
@click.option("--host", default=None, metavar="ADDRESS",
              help="Interface the local cluster and its dashboard listen on. [default: 127.0.0.1]")
@click.option("--serial", is_flag=True, help="Run the points one after another in this process, without Dask.")
@click.option("--backend", type=click.Choice(["cpu", "cuda", "reference"]), default=None,
              help="Backend of every run, in place of the sweep file's. cuda runs the points that share a "
                   "shape as ensembles, in this process on its GPU, or on the GPU workers of --scheduler. "
                   "[default: the sweep file's, else cpu]")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar, no summary.")
def sweep(sweep_file, out, results, scheduler, workers, host, serial, backend, quiet):
    """Run every point of a sweep file and gather the results into an xarray Dataset.

    Each finished point is stored at once in OUT/points/<id>.json; running the same
    command again computes only the points that are missing or failed.

    \b
    Examples:
      flocking sweep examples/vicsek1995.toml --out vicsek
      flocking sweep grid.toml --scheduler tcp://login1:8786
      flocking sweep grid.toml --serial --results grid.zarr
      flocking sweep grid.toml --backend cuda
    """
    from ..sweep import require
    from ..sweep.spec import SweepSpec

    if serial and (scheduler or workers or host):
        raise ParameterError("serial: runs in this process; leave out --scheduler, --workers and --host")
    spec = SweepSpec.load(sweep_file)
    if backend is not None:
        spec = spec.with_backend(backend)
    gpu = any(p.config.backend == "cuda" for p in spec.points())
    if gpu and not scheduler and (workers or host):
        option = "workers" if workers else "host"
        raise ParameterError(f"{option}: a cuda sweep without --scheduler runs its ensembles in this process, "
                             f"on this machine's GPU; leave out --workers and --host")
    out = out or os.path.splitext(os.path.basename(sweep_file))[0]
    if os.path.exists(out) and not os.path.isdir(out):
        raise ParameterError(f"out: {out!r} exists and is not a folder")
    results = results or os.path.join(out, "results.nc")
    from ..sweep.results import check_results_path, gather, save

    check_results_path(results)
    serial = serial or (gpu and not scheduler)
    dask = () if serial else ("dask", "distributed") + (() if scheduler else ("cryptography",))
    require("xarray", "netCDF4" if results.endswith(".nc") else "zarr", *dask)
    from ..sweep.executors import Dask, Serial, gpu_here, reach
    from ..sweep.runner import PointStore, execute

    say = (lambda text: None) if quiet else (lambda text: click.echo(text, err=True))
    executor = Serial() if serial else Dask(scheduler=scheduler, workers=workers, host=host, report=say)
    if scheduler:
        reach(scheduler)  # before anything is said or written
    elif gpu:
        gpu_here()
    store = PointStore(out)
    points = list({p.id: p for p in spec.points()}.values())
    states = [store.state(p) for p in points]
    stored, outdated = states.count("done"), states.count("outdated")
    say(f"flocking sweep: {len(points)} runs ({stored} stored, {len(points) - stored} to run) -> {out}")
    if outdated:
        say(f"flocking sweep: {outdated} stored runs were measured by an older flocking, without "
            f"within-run errors or the order of each species and the nematic order; they run again")
    start = time.perf_counter()
    try:
        summary = execute(spec, out, executor, progress=not quiet, report=lambda text: click.echo(text, err=True))
    except KeyboardInterrupt:
        done = sum(store.is_done(p) for p in points)
        click.echo(f"flocking sweep: interrupted; {done} of {len(points)} runs stored in {out}; "
                   f"run the same command again to resume", err=True)
        sys.exit(130)
    save(gather(spec, out), results)
    elapsed = time.perf_counter() - start
    say(f"flocking sweep: {summary['done']} run, {summary['failed']} failed, {summary['skipped']} already "
        f"stored, in {elapsed:.1f} s on {summary['where']}; wrote {results}")
    if summary["failed"]:
        click.echo(f"flocking sweep: {summary['failed']} runs failed (recorded in {out}/points); "
                   f"run the same command again to retry them", err=True)
        sys.exit(1)


@click.command("plot-sweep")
@click.argument("results", metavar="RESULTS")
@click.option("--view", type=click.Choice(["order", "fss"]), default="order", show_default=True,
              help="order: order, susceptibility and Binder cumulant against --x; fss: Binder cumulant "
                   "crossings and the peak susceptibility against the system size.")
@click.option("--x", "x", default=None, help="Swept parameter on the horizontal axis. "
              "[default: the first that is not a system size]")
@click.option("--theme", type=click.Choice(["dark", "light"]), default="dark", show_default=True,
              help="dark for screens and slides, light for paper.")
@click.option("--size", type=click.Choice(["column", "page", "slide"]), default="page", show_default=True,
              help="Width and fonts for a paper column (panels stacked), a page or a slide.")
@click.option("--dpi", type=click.FloatRange(min=10, max=2000), default=None,
              help="Pixels per inch of a .png. [default: 200]")
@click.option("--out", default=None, help="Figure file: .png, .svg or .pdf. [default: RESULTS with .png, "
              "or with -fss.png for --view fss]")
def plot_sweep(results, view, x, theme, size, dpi, out):
    """Plot a sweep: one curve per system size (and per value of any other swept parameter).

    RESULTS is a results file (.nc, .zarr) or a sweep output folder. Points are means over
    replicas; an error bar is the larger of the error within the runs (from the
    autocorrelation time) and the scatter between replicas, as the caption says.

    \b
    Examples:
      flocking plot-sweep vicsek/results.nc
      flocking plot-sweep vicsek --x noise --out fig2a.pdf --theme light --size column
      flocking plot-sweep vicsek --view fss --out fss.png
    """
    from ..sweep import require
    from ..viz import style

    if out is None:
        base = results.rstrip("/")
        base = os.path.join(base, "results") if os.path.isdir(base) and not base.endswith(".zarr") else base
        out = os.path.splitext(base)[0] + ("-fss" if view == "fss" else "") + ".png"
    style.check_format(out)
    require("xarray")
    from ..sweep.figures import plot
    from ..sweep.results import open_results

    ds = open_results(results)
    click.echo(f"flocking plot-sweep: wrote {plot(ds, out, x, view=view, theme=theme, size=size, dpi=dpi)}",
               err=True)
