"""``flocking analyze RUN_DIR``: every measurement of a run, as JSON, CSV and PNG files."""

from __future__ import annotations

import csv
import json
import os

import click

from ..files import replace_atomically
from ..model import ParameterError

QUANTITIES = ("polar", "fluctuations", "correlation", "profile", "clusters", "boxcount", "msd")

#: quantity -> (CSV/PNG file stem, CSV columns as (header, attribute))
OUTPUTS = {
    "polar": ("polar_order_window", [("step", "steps"), ("polar_order", "series"), ("in_window", "window")]),
    "fluctuations": ("number_fluctuations", [("side", "sizes"), ("mean_n", "mean"), ("dn", "std"),
                                             ("fitted", "fitted")]),
    "correlation": ("velocity_correlation", [("r", "r"), ("C", "correlation"), ("pairs", "pairs")]),
    "profile": ("density_profile", [("x", "x"), ("density", "density")]),
    "clusters": ("cluster_sizes", [("size", "size_values"), ("count", "size_counts")]),
    "boxcount": ("box_counting", [("eps", "scales"), ("boxes", "counts"), ("fitted", "fitted")]),
    "msd": ("msd", [("lag", "lags"), ("msd", "msd"), ("origins", "origins")]),
}


def parse_only(text: str | None) -> list[str]:
    if not text:
        return list(QUANTITIES)
    chosen = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in chosen if t not in QUANTITIES]
    if bad or not chosen:
        raise ParameterError(f"only: must be a comma-separated list of {', '.join(QUANTITIES)} (got {text!r})")
    return chosen


def parse_start(text: str | None):
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"start: must be a step >= 0 or a fraction in (0, 1) (got {text!r})") from None
    return int(value) if value >= 1 and value == int(value) else value


def build(name: str, model, start, frames, radius, r_max, dr, method):
    """The analysis object for ``name`` with the options of the command."""
    from .. import analysis as fa

    if name == "polar":
        return fa.PolarOrder(start=start)
    if name == "fluctuations":
        return fa.NumberFluctuations(start=start, frames=frames)
    if name == "correlation":
        return fa.VelocityCorrelation(r_max=r_max, dr=dr, method=method, start=start, frames=frames)
    if name == "profile":
        return fa.DensityProfile(start=start, frames=frames)
    if name == "clusters":
        return fa.Clusters(radius=radius if radius is not None else (model.radius if model else None),
                           start=start, frames=frames)
    if name == "boxcount":
        return fa.BoxCounting(start=start)
    return fa.MeanSquareDisplacement(start=start, frames=frames)


@click.command()
@click.argument("run_dir", type=click.Path())
@click.option("--only", default=None, help=f"Comma-separated subset of: {', '.join(QUANTITIES)}. [default: all]")
@click.option("--start", default=None,
              help="Window: first step kept, or a fraction in (0, 1) of the run to discard. [default: 0]")
@click.option("--frames", type=click.INT, default=None,
              help="Use at most the last N frames of the window (the polar order uses every step).")
@click.option("--radius", type=click.FLOAT, default=None, help="Cluster link radius. [default: the run's radius]")
@click.option("--r-max", type=click.FLOAT, default=None, help="Largest distance of C(r). [default: L/2]")
@click.option("--dr", type=click.FLOAT, default=None, help="Bin width of C(r). [default: min(0.5, r_max/20)]")
@click.option("--method", type=click.Choice(["auto", "cells", "grid"]), default="auto",
              help="C(r): exact cell list, FFT grid, or auto. [default: auto]")
@click.option("--out", default=None, help="Output folder. [default: RUN_DIR]")
@click.option("--no-plots", is_flag=True, help="Write JSON and CSV only.")
@click.option("--quiet", "-q", is_flag=True, help="No summary on stderr.")
def analyze(run_dir, only, start, frames, radius, r_max, dr, method, out, no_plots, quiet):
    """Measure a run: polar order, number fluctuations, velocity correlation, density
    profile, clusters, box-counting dimension and MSD.

    RUN_DIR is a folder written by `flocking run` (or a GSD file). Writes analysis.json,
    one CSV per curve and one PNG per quantity into RUN_DIR (or --out).

    \b
    Examples:
      flocking analyze runs/run-0001
      flocking analyze runs/run-0001 --only polar,fluctuations --start 0.5
      flocking analyze traj.gsd --frames 20 --r-max 20 --out results
    """
    import warnings

    from ..analysis import _input

    names = parse_only(only)
    start = parse_start(start)
    if frames is not None and frames < 1:
        raise ParameterError(f"frames: must be a whole number >= 1 (got {frames})")
    if not os.path.exists(run_dir):
        raise ParameterError(f"RUN_DIR {run_dir!r}: no such folder or file")
    folder = run_dir if os.path.isdir(run_dir) else os.path.dirname(os.path.abspath(run_dir))
    gsd_path = _input.trajectory_path(run_dir) if (not os.path.isdir(run_dir) or os.path.exists(
        os.path.join(run_dir, "trajectory.gsd"))) else None
    obs = os.path.join(folder, "observables.csv") if os.path.isdir(run_dir) else None
    if gsd_path is None and not (obs and os.path.exists(obs) and names == ["polar"]):
        raise ParameterError(f"RUN_DIR {run_dir!r}: holds no trajectory.gsd")
    out = out or folder
    if os.path.exists(out) and not os.path.isdir(out):
        raise ParameterError(f"out: {out!r} exists and is not a folder")
    model = _input.model_of(gsd_path) if gsd_path else None
    objects = {name: build(name, model, start, frames, radius, r_max, dr, method) for name in names}
    try:
        system = _input.as_frames(gsd_path) if gsd_path else None
    except ParameterError as err:
        raise ParameterError(f"RUN_DIR {run_dir!r}: {str(err).partition(': ')[2]}") from None
    results, notes = {}, {}
    for name, obj in objects.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                if name == "polar":
                    source = run_dir if obs and os.path.exists(obs) else system
                    obj.compute(source, n=model.n if model else None)
                else:
                    obj.compute(system)
            except ParameterError as err:
                if name in ("correlation", "polar") and "needs velocities" in str(err):
                    notes[name] = str(err)
                    continue
                key, _, rest = str(err).partition(": ")
                if key == "system":  # the input itself: name it as the user typed it
                    raise ParameterError(f"RUN_DIR {run_dir!r}: {rest}") from None
                raise
        if caught:
            notes[name] = "; ".join(str(w.message) for w in caught)
        results[name] = obj
    os.makedirs(out, exist_ok=True)
    summary = {"run": os.path.abspath(run_dir), "model": model.to_dict() if model else None,
               "start": start, "frames": frames, "notes": notes}
    summary.update({name: obj.to_dict() for name, obj in results.items()})
    for name, obj in results.items():
        stem, columns = OUTPUTS[name]
        write_csv(os.path.join(out, stem + ".csv"), obj, columns)
        if not no_plots:
            plot(obj, os.path.join(out, stem + ".png"))
    write_json(os.path.join(out, "analysis.json"), summary)
    if not quiet:
        for line in summary_lines(results):
            click.echo(line, err=True)
        for name, note in notes.items():
            click.echo(f"flocking analyze: {name}: {note}", err=True)
        click.echo(f"flocking analyze: wrote {os.path.join(out, 'analysis.json')}", err=True)


def write_csv(path: str, obj, columns) -> None:
    values = [getattr(obj, attr) for _, attr in columns]
    with replace_atomically(path, newline="") as f:
        writer = csv.writer(f)
        writer.writerow([h for h, _ in columns])
        for row in zip(*[v.tolist() for v in values]):
            writer.writerow([int(x) if isinstance(x, bool) else x for x in row])


def write_json(path: str, data: dict) -> None:
    with replace_atomically(path) as f:
        json.dump(data, f, indent=1)


def plot(obj, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    obj.plot(ax)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summary_lines(results) -> list[str]:
    lines = []
    for name, obj in results.items():
        if name == "polar":
            lines.append(f"polar order: {obj.mean:.4g} ± {obj.mean_error:.2g}, chi {obj.susceptibility:.4g}, "
                         f"G {obj.binder:.4g} (tau {obj.tau:.3g} samples)")
        elif name == "fluctuations":
            lines.append(f"number fluctuations: alpha {obj.alpha:.3f} ± {obj.alpha_error:.3f}")
        elif name == "correlation":
            lines.append(f"velocity correlation: first zero {obj.correlation_length:.4g}")
        elif name == "profile":
            lines.append(f"density profile: {obj.band_count} band(s), width {obj.band_width:.3g}, "
                         f"speed {obj.band_speed:.3g}")
        elif name == "clusters":
            lines.append(f"clusters: {obj.num_clusters}, largest fraction {obj.largest_fraction:.3f}")
        elif name == "boxcount":
            lines.append(f"box counting: D {obj.dimension:.3f} ± {obj.dimension_error:.3f}")
        elif name == "msd":
            lines.append(f"MSD: {len(obj.lags)} lags, up to {obj.msd[-1]:.4g} at lag {obj.lags[-1]}")
    return [f"flocking analyze: {line}" for line in lines]
