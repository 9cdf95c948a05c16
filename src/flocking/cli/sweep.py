"""``flocking sweep`` and ``flocking plot-sweep``: phase diagrams from one sweep file."""

from __future__ import annotations

import os
import sys
import time

import click

from ..model import ParameterError
from . import options as opt


@click.command(short_help="Run every point of a sweep file (a phase diagram).")
@click.argument("sweep_file", metavar="SWEEP.toml", type=click.Path(dir_okay=False))
@opt.out("Output folder.", "the sweep file's name, here")
@click.option("--results", default=None,
              help="Results file, .nc (netCDF) or .zarr.  [default: OUT/results.nc]")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Address of a running Dask scheduler, e.g. tcp://10.0.0.1:8786.  [default: a local cluster]")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Worker processes of the local cluster.  [default: one per core]")
@click.option("--host", default=None, metavar="ADDRESS",
              help="Interface the local cluster and its dashboard listen on.  [default: 127.0.0.1]")
@click.option("--serial", is_flag=True, help="Run the points one after another in this process, without Dask.")
@opt.backend("Backend of every run, in place of the sweep file's. cuda runs the points that share a shape as "
             "ensembles, in this process on its GPU, or on the GPU workers of --scheduler.",
             "the sweep file's, else cpu")
@opt.quiet()
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
    opt.check_folder("out", out)
    results = results or os.path.join(out, "results.nc")
    from ..sweep.results import check_results_path, gather, save

    check_results_path(results)
    opt.check_folder("results", os.path.dirname(os.path.abspath(results)))
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
        f"stored, in {elapsed:.1f} s {place(summary['where'])}; wrote {results}")
    if summary["failed"]:
        click.echo(f"flocking sweep: {summary['failed']} runs failed (recorded in {out}/points); "
                   f"run the same command again to retry them", err=True)
        sys.exit(1)


def place(where: str) -> str:
    """Where an executor ran the points, in the summary's words.

    >>> place("in-process"), place("2 Dask workers at tcp://127.0.0.1:4242")
    ('in this process', 'on 2 Dask workers at tcp://127.0.0.1:4242')
    """
    return "in this process" if where == "in-process" else f"on {where}"


@click.command("plot-sweep", short_help="Plot a sweep: order, susceptibility, Binder cumulant.")
@click.argument("results", metavar="RESULTS")
@click.option("--view", type=opt.OneOf(["order", "fss"]), default="order", show_default=True,
              help="order: order, susceptibility and Binder cumulant against --x; fss: Binder cumulant "
                   "crossings and the peak susceptibility against the system size.")
@click.option("--x", "x", default=None, help="Swept parameter on the horizontal axis.  "
              "[default: the first that is not a system size]")
@opt.theme
@opt.size
@opt.dpi()
@opt.out("Figure file: .png, .svg or .pdf (the extension decides).",
         "RESULTS with .png, or with -fss.png for --view fss")
@opt.quiet("Nothing on stderr.")
def plot_sweep(results, view, x, theme, size, dpi, out, quiet):
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

    if out is None:
        base = results.rstrip("/")
        base = os.path.join(base, "results") if os.path.isdir(base) and not base.endswith(".zarr") else base
        out = os.path.splitext(base)[0] + ("-fss" if view == "fss" else "") + ".png"
    if os.path.splitext(out)[1].lower().lstrip(".") not in opt.FORMATS:
        raise ParameterError(f"out: must end in .png, .svg or .pdf (got {out!r})")
    opt.check_file("out", out)
    require("xarray")
    from ..sweep.figures import plot
    from ..sweep.results import open_results

    ds = open_results(results)
    path = plot(ds, out, x, view=view, theme=theme, size=size, dpi=dpi)
    if not quiet:
        click.echo(f"flocking plot-sweep: wrote {path}", err=True)
