"""``flocking analyze RUN_DIR``: every measurement of a run, as JSON, CSV and figure files.

The window of steps analysed is the same for every quantity: the end of the transient
found in the polar order (``PolarOrder(start="auto")``), half the run when none can be
found, or ``--start``. Times are in the model's units, ``t = step * dt``.
"""

from __future__ import annotations

import csv
import json
import math
import os
import warnings

import click

from ..files import replace_atomically
from ..model import ParameterError
from . import options as opt

QUANTITIES = ("polar", "species", "nematic", "fluctuations", "structure", "correlation", "profile", "clusters",
              "boxcount", "msd")
#: quantities measured by default only when the run records them (several species; nematic alignment)
OPTIONAL = ("species", "nematic")
#: quantities that read observables.csv (every step) when the run folder has one
SERIES = ("polar", "species", "nematic")
#: quantities that coarse-grained fields (fields.nc) give, with --from-fields
FROM_FIELDS = ("fluctuations", "structure")

#: quantities whose distribution over the window is written too: quantity -> (file stem, figure title)
HISTOGRAMS = {"polar": ("polar_order_histogram", "Distribution of the polar order"),
              "nematic": ("nematic_order_histogram", "Distribution of the nematic order")}

#: quantity -> (file stem, figure title, CSV columns as (header, attribute)); a header
#: ``None`` is named for the profile's axis
OUTPUTS = {
    "polar": ("polar_order_window", "Polar order",
              [("step", "steps"), ("time", "times"), ("polar_order", "series"), ("in_window", "window")]),
    "species": ("polar_order_species", "Polar order per species",
                [("step", "steps"), ("time", "times"), ("in_window", "window")]),
    "nematic": ("nematic_order_window", "Nematic order",
                [("step", "steps"), ("time", "times"), ("nematic_order", "series"), ("in_window", "window")]),
    "fluctuations": ("number_fluctuations", "Number fluctuations",
                     [("side", "sizes"), ("mean_n", "mean"), ("dn", "std"), ("fitted", "fitted")]),
    "structure": ("structure_factor", "Structure factor",
                  [("k", "k"), ("S", "s"), ("S_error", "s_error"), ("wavevectors", "counts")]),
    "correlation": ("velocity_correlation", "Velocity correlation",
                    [("r", "r"), ("C", "correlation"), ("pairs", "pairs")]),
    "profile": ("density_profile", "Density profile, last frame", [(None, "x"), ("density", "density")]),
    "clusters": ("cluster_sizes", "Cluster sizes",
                 [("size", "size_values"), ("clusters_all_frames", "size_counts_total"),
                  ("clusters_per_frame", "size_counts_per_frame")]),
    "boxcount": ("box_counting", "Box counting, last frame",
                 [("eps", "scales"), ("boxes", "counts"), ("fitted", "fitted")]),
    "msd": ("msd", "Mean square displacement",
            [("lag_steps", "lag_steps"), ("lag_time", "lag_times"), ("msd", "msd"), ("origins", "origins")]),
}


def written_stems() -> tuple[str, ...]:
    """The stems of every file the command writes besides ``analysis.json`` (each as
    ``.csv`` and as a figure): what a run folder may hold of an earlier analysis."""
    return tuple(stem for stem, *_ in (*OUTPUTS.values(), *HISTOGRAMS.values()))


def parse_only(text: str | None) -> list[str]:
    """The quantities asked for; every one when ``text`` is empty (:data:`OPTIONAL` ones are
    then kept only where the run records them: see :func:`recorded`)."""
    if not text:
        return list(QUANTITIES)
    chosen = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in chosen if t not in QUANTITIES]
    if bad or not chosen:
        raise ParameterError(f"only: must be a comma-separated list of {', '.join(QUANTITIES)} (got {text!r})")
    return chosen


def parse_start(text: str | None):
    """``"auto"``, a whole step, or a fraction in (0, 1)."""
    if text is None or text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise ParameterError(f"start: must be auto, a step >= 0 or a fraction in (0, 1) (got {text!r})") from None
    if not math.isfinite(value) or value < 0 or (value >= 1 and value != int(value)):
        raise ParameterError(f"start: must be auto, a whole step >= 0 or a fraction in (0, 1) (got {text!r})")
    return int(value) if value >= 1 or value == 0 else value


def build(name: str, model, start, frames, options: dict):
    """The analysis object for ``name`` with the options of the command."""
    from .. import analysis as fa

    if name == "polar":
        return fa.PolarOrder(start=start)
    if name == "species":
        return fa.PerSpecies(fa.PolarOrder(start=start))
    if name == "nematic":
        return fa.NematicOrder(start=start)
    if name == "fluctuations":
        return fa.NumberFluctuations(start=start, frames=frames)
    if name == "structure":
        return fa.StructureFactor(k_max=options["k_max"], start=start, frames=frames)
    if name == "correlation":
        return fa.VelocityCorrelation(r_max=options["r_max"], dr=options["dr"], method=options["method"],
                                      start=start, frames=frames)
    if name == "profile":
        return fa.DensityProfile(start=start, frames=frames)
    if name == "clusters":
        k = options["cluster_k"]
        if k is not None and model is not None and k >= model.n:
            raise ParameterError(f"k: must be at most the number of other particles, {model.n - 1} (got {k})")
        radius = options["radius"]
        if radius is None and k is None and model is not None:
            radius = model.radius
        return fa.Clusters(radius=radius, k=k, start=start, frames=frames)
    if name == "boxcount":
        return fa.BoxCounting(start=start)
    return fa.MeanSquareDisplacement(max_lag=options["max_lag"], start=start, frames=frames)


#: options of the command whose values reach an analysis under another name
RENAMED = {"radius": "cluster_radius", "k": "cluster_k"}


@click.command(short_help="Measure a run: order, fluctuations, correlation, bands, clusters.")
@click.argument("run_dir", type=click.Path())
@click.option("--only", default=None,
              help=f"Comma-separated subset of: {', '.join(QUANTITIES)}. [default: all; species and nematic when "
                   "the run has several species or nematic alignment]")
@click.option("--start", default="auto", show_default=True,
              help="First step of the window, a fraction in (0, 1) of the run to discard, or auto: the end of "
                   "the transient detected in the polar order (half the run when none is found).")
@click.option("--frames", type=click.INT, default=None,
              help="Use at most the last N frames of the window (the polar order uses every step).  [default: all]")
@click.option("--max-lag", type=click.INT, default=None,
              help="Largest lag of the mean square displacement, in steps.  [default: all]")
@click.option("--bins", type=click.INT, default=50, show_default=True,
              help="Bins over [0, 1] of the distribution of the polar (and nematic) order in the window.")
@click.option("--cluster-radius", type=click.FLOAT, default=None,
              help="Two particles closer than this are in one cluster.  [default: the run's radius]")
@click.option("--cluster-k", type=click.INT, default=None,
              help="Link each particle with its k nearest instead of by distance.")
@click.option("--r-max", type=click.FLOAT, default=None, help="Largest distance of C(r).  [default: L/2]")
@click.option("--dr", type=click.FLOAT, default=None, help="Bin width of C(r).  [default: min(0.5, r_max/20)]")
@click.option("--method", type=opt.OneOf(("auto", "cells", "grid")), default="auto", show_default=True,
              help="C(r): cells (exact, over pairs), grid (FFT), or auto.")
@click.option("--k-max", type=click.FLOAT, default=None,
              help="Largest wavenumber of S(k), in units of 1/R.  [default: 32 shells along the shortest side "
                   "(12 in 3D); from fields, half the grid's Nyquist]")
@click.option("--from-fields", is_flag=True,
              help="Number fluctuations and S(k) from the run's fields.nc (every fields frame in the window) "
                   "instead of the trajectory's particles.")
@opt.out("Output folder.", "RUN_DIR")
@opt.theme
@opt.size
@opt.picture_format
@opt.dpi()
@opt.plots("A figure per quantity (without: JSON and CSV only).")
@opt.quiet("No summary on stderr.")
def analyze(run_dir, only, start, frames, max_lag, bins, cluster_radius, cluster_k, r_max, dr, method, k_max, from_fields, out,
            theme, size, fmt, dpi, plots, quiet):
    """Measure a run: polar order, number fluctuations, structure factor, velocity
    correlation, density profile, clusters, box-counting dimension and MSD; the polar order of each species
    and the nematic order when the run has several species or nematic alignment.

    RUN_DIR is a folder written by `flocking run` (or a GSD file). Writes analysis.json,
    one CSV per curve and one figure per quantity into RUN_DIR (or --out). The transient
    is left out: the window starts where the polar order has settled (or at --start).

    \b
    Examples:
      flocking analyze runs/run-0001
      flocking analyze runs/run-0001 --only polar,fluctuations --start 0.5
      flocking analyze big --only polar,fluctuations,structure --from-fields
      flocking analyze traj.gsd --frames 20 --r-max 20 --out results --theme light --format pdf
    """
    from ..analysis import snapshots
    from ..analysis.order import histogram_bins
    from ..viz import style

    names = parse_only(only)
    asked = only is not None
    start = parse_start(start)
    for option, value in (("frames", frames), ("max_lag", max_lag)):
        if value is not None and value < 1:
            raise ParameterError(f"{option}: must be a whole number >= 1 (got {value})")
    histogram_bins(bins)
    if not os.path.exists(run_dir):
        raise ParameterError(f"RUN_DIR {run_dir!r}: no such folder or file")
    folder = run_dir if os.path.isdir(run_dir) else os.path.dirname(os.path.abspath(run_dir))
    gsd_path = snapshots.trajectory_path(run_dir) if (not os.path.isdir(run_dir) or os.path.exists(
        os.path.join(run_dir, "trajectory.gsd"))) else None
    obs = os.path.join(folder, "observables.csv") if os.path.isdir(run_dir) else None
    obs = obs if obs and os.path.exists(obs) else None
    model = snapshots.model_of(gsd_path) if gsd_path else None
    if not asked:
        names = [name for name in names if name not in OPTIONAL or recorded(name, model, obs, gsd_path)]
    fields_path = os.path.join(folder, "fields.nc") if from_fields else None
    if fields_path and not os.path.exists(fields_path):
        raise ParameterError(f"from_fields: {folder!r} holds no fields.nc (flocking run --fields BIN writes it)")
    if gsd_path is None and not (obs and set(names) <= set(SERIES) | set(FROM_FIELDS if fields_path else ())):
        raise ParameterError(f"RUN_DIR {run_dir!r}: holds no trajectory.gsd")
    out = out or folder
    opt.check_folder("out", out)
    options = {"radius": cluster_radius, "cluster_k": cluster_k, "r_max": r_max, "dr": dr, "method": method, "max_lag": max_lag,
               "k_max": k_max}
    for name in names:  # every option checked before anything is read or written
        try:
            build(name, model, None, frames, options)
        except ParameterError as err:
            key, _, rest = str(err).partition(": ")
            raise ParameterError(f"{RENAMED.get(key, key)}: {rest}") from None
    try:
        system = snapshots.as_frames(gsd_path) if gsd_path else None
    except ParameterError as err:
        raise ParameterError(f"RUN_DIR {run_dir!r}: {str(err).partition(': ')[2]}") from None
    polar_source = run_dir if obs else system
    series_source = run_dir if os.path.isdir(run_dir) else system
    window = choose_window(start, polar_source, system, model, window_candidates(names, series_source),
                           series_source)
    objects = {name: build(name, model, "auto" if name == "polar" and window["by"] == "polar order" else
                           window["start"], frames, options) for name in names}
    results, notes, skipped = {}, {}, {}
    for name, obj in objects.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                if name == "polar":
                    obj.compute(polar_source, n=model.n if model else None)
                elif name in SERIES:  # observables.csv where it has the column, else the trajectory
                    obj.compute(series_source)
                elif fields_path and name in FROM_FIELDS:
                    obj.compute(fields_path)
                else:
                    obj.compute(system)
            except ParameterError as err:
                key, _, rest = str(err).partition(": ")
                if key != "system":  # an option's value: the user's to change
                    raise
                notes[name] = f"skipped: {rest}"
                skipped[name] = rest
                continue
        messages = [hint(name, obj, str(w.message)) for w in caught] + list(obj.notes)
        if any(messages):
            notes[name] = "; ".join(m for m in messages if m)
        results[name] = obj
    if not results:
        raise ParameterError(f"RUN_DIR {run_dir!r}: " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    os.makedirs(out, exist_ok=True)
    summary = {"run": os.path.abspath(run_dir), "model": model.to_dict() if model else None,
               "window": {"start_step": window["step"], "rule": window["rule"]}, "frames": frames,
               "time_unit": "t = step * dt", "notes": notes}
    summary.update({name: obj.to_dict() for name, obj in results.items()})
    details = caption(model, system, window)
    for name, obj in results.items():
        stem, heading, columns = OUTPUTS[name]
        write_csv(os.path.join(out, stem + ".csv"), obj, columns_of(name, obj, columns))
        if plots is not False:
            fig, ax = style.figure(size, theme=theme)
            obj.plot(ax)
            style.title(fig, heading, details)
            style.save(fig, os.path.join(out, f"{stem}.{fmt}"), dpi=dpi)
        if name in HISTOGRAMS:
            stem, heading = HISTOGRAMS[name]
            write_histogram(os.path.join(out, stem + ".csv"), obj.histogram(bins))
            if plots is not False:
                fig, ax = style.figure(size, theme=theme)
                obj.plot_histogram(ax, bins=bins)
                style.title(fig, heading, details)
                style.save(fig, os.path.join(out, f"{stem}.{fmt}"), dpi=dpi)
    write_json(os.path.join(out, "analysis.json"), summary)
    if not quiet:
        for line in [window_line(window)] + summary_lines(results):
            click.echo(f"flocking analyze: {line}", err=True)
        for name, note in notes.items():
            click.echo(f"flocking analyze: {name}: {note}", err=True)
        click.echo(f"flocking analyze: wrote {os.path.join(out, 'analysis.json')}", err=True)


def recorded(name: str, model, obs: str | None, gsd_path: str | None) -> bool:
    """Whether the run records ``name`` (of :data:`OPTIONAL`): several species (in its
    model, the ``polar_order_<name>`` columns of observables.csv or its GSD particle
    types), or nematic alignment (its model, or a ``nematic_order`` column)."""
    from ..analysis import order

    if model is not None:
        return len(model.species_names) > 1 if name == "species" else model.alignment_rule == "nematic"
    columns = order.csv_columns(obs) if obs else []
    if name == "nematic":
        return "nematic_order" in columns
    if any(c.startswith("polar_order_") for c in columns):
        return True
    try:
        return gsd_path is not None and len(order.species_names(gsd_path)) > 1
    except ParameterError:  # an unreadable file: reported once it is opened
        return False


def columns_of(name: str, obj, columns) -> list:
    """``(header, attribute or values)`` of a quantity's CSV: per species, one
    ``polar_order_<name>`` column each, before ``in_window``."""
    if name != "species":
        return columns
    return columns[:2] + [(f"polar_order_{s}", obj[s].series) for s in obj.names] + columns[2:]


def choose_window(start, polar_source, frames, model, others=(), others_source=None) -> dict:
    """``{"start": what each quantity takes, "step": first step, "rule": how, "by": the
    series whose transient set it}``. With ``start="auto"``: the latest end of a transient
    among the polar order and the ``others`` (``(label, quantity with start="auto")``
    pairs, computed on ``others_source``), so that no series measured keeps its transient."""
    from ..analysis import PolarOrder

    if start != "auto":
        return {"start": start, "step": start if isinstance(start, int) else None, "rule": "--start", "by": None}
    last = int(frames.steps[-1]) if frames is not None else None
    polar = auto_window(PolarOrder(start="auto"), polar_source, n=model.n if model else None)
    if polar is None:
        if frames is not None and len(frames) >= 2:
            step = int(frames.steps[len(frames) // 2])
            return {"start": step, "step": step, "rule": "half the run (no polar order to find the transient in)",
                    "by": None}
        return {"start": None, "step": int(frames.steps[0]) if frames is not None else 0,
                "rule": "the whole run (a single frame)", "by": None}
    chosen, by = polar, "polar order"
    for label, quantity in others:
        other = auto_window(quantity, others_source)
        if other is not None and other.window_start > chosen.window_start:
            chosen, by = other, label
    step = chosen.window_start if last is None else min(chosen.window_start, last)
    where = "" if by == "polar order" else f" in the {by}"
    if chosen.window_rule != "detected":
        rule = f"half the run (no steady window found{where})"
    else:
        rule = f"transient detected{where}" if step > polar.steps[0] else "no transient found"
    return {"start": step, "step": step, "rule": rule, "by": by}


def auto_window(quantity, source, **options):
    """``quantity`` (with ``start="auto"``) computed on ``source``, or ``None`` when the
    source cannot give it (no velocities, a single value: no transient to find)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return quantity.compute(source, **options)
    except ParameterError:
        return None


def window_candidates(names, source) -> list:
    """The series besides the polar order whose transients the window leaves out: the
    nematic order and each species' polar order, when measured."""
    from .. import analysis as fa
    from ..analysis.order import species_names

    others = []
    if "nematic" in names:
        others.append(("nematic order", fa.NematicOrder(start="auto")))
    if "species" in names:
        try:
            species = species_names(source)
        except ParameterError:
            species = ()
        others += [(f"polar order of species {s}", fa.PolarOrder(start="auto", species=s))
                   for s in (species if len(species) > 1 else ())]
    return others


def window_text(window: dict) -> str:
    """Where the window starts, and why."""
    if window["step"] is None:
        return f"the first {window['start']:.0%} of the run left out (--start)"
    return f"from step {window['step']} ({window['rule']})"


def window_line(window: dict) -> str:
    if window["rule"] == "--start":
        return f"window: {window_text(window)}"
    return f"window: {window_text(window)[:-1]}; --start STEP to choose)"


def hint(name: str, obj, message: str) -> str:
    """A warning of a quantity in the command's terms (``""`` to leave it out)."""
    if name in ("polar", "nematic") and obj.computed and not obj.equilibrated:
        return (f"the window from step {obj.window_start} does not look equilibrated (its halves differ by "
                f"{abs(obj.drift):.1f} errors): discard more with --start {obj.suggested_start}")
    if name == "boxcount" and "two box sizes" in message:
        return "the dimension comes from two box sizes only (more particles give more): no error estimate"
    return message


def caption(model, frames, window) -> str:
    """The parameters that matter, joined by `` · ``, for the figures' captions."""
    parts = []
    if model is not None:
        box = model.box
        side = f"{box[0]:.4g}" if len(set(box)) == 1 else " × ".join(f"{b:.4g}" for b in box)
        reach = {"metric": f"R = {model.radius:g}", "topological": f"k = {model.k} (topological)"}.get(
            model.neighbours, model.neighbours)
        parts = [f"{model.dim}D", f"N = {model.n}", f"L = {side}", f"ρ = {model.n / math.prod(box):.3g}",
                 f"v₀ = {model.speed:g}" + (" (uniform)" if model.speeds == "uniform" else ""), reach,
                 f"η = {model.noise:.3g} ({model.noise_type})", f"Δt = {model.dt:g}"]
        if model.alignment != 1:
            parts.append(f"ε = {model.alignment:g}")
        if model.delay:
            parts.append(f"delay {model.delay}")
        if model.update != "backward":
            parts.append(f"{model.update} update")
        if len(model.species_names) > 1:
            parts.append(f"species {', '.join(model.species_names)}")
        if model.alignment_rule == "nematic":
            parts.append("nematic alignment")
    elif frames is not None:
        first = frames[0]
        parts = [f"{first.dim}D", f"N = {first.n}", "L = " + " × ".join(f"{b:.4g}" for b in first.box)]
    parts.append(window_text(window))
    return " · ".join(parts)


def write_csv(path: str, obj, columns) -> None:
    values = [getattr(obj, attr) if isinstance(attr, str) else attr for _, attr in columns]
    headers = [h if h is not None else profile_axis(obj) for h, _ in columns]
    with replace_atomically(path, newline="") as f:
        writer = csv.writer(f)
        writer.writerow(headers)
        for row in zip(*[v.tolist() for v in values]):
            writer.writerow([int(x) if isinstance(x, bool) else x for x in row])


def write_histogram(path: str, hist) -> None:
    """A distribution's CSV: ``low, high, count, density``, a row per bin."""
    with replace_atomically(path, newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["low", "high", "count", "density"])
        for row in zip(hist.edges[:-1].tolist(), hist.edges[1:].tolist(), hist.counts.tolist(),
                       hist.density.tolist()):
            writer.writerow(row)


def write_json(path: str, data: dict) -> None:
    with replace_atomically(path) as f:
        json.dump(data, f, indent=1)


def profile_axis(profile) -> str:
    """The name of a density profile's coordinate: its axis, or ``s`` along a diagonal."""
    return "xyz"[profile.axis_used] if profile.axis_used is not None else "s"


def profile_line(obj) -> str:
    """The summary of a density profile: where it runs, and its bands or why none."""
    axis = profile_axis(obj)
    where = axis
    if axis == "s":
        where = "(" + ", ".join(map(str, obj.lattice)) + ")" + (f", {obj.angle:.0f}° from x" if math.isfinite(
            obj.angle) else "")
    if not obj.frames_with_bands:
        return f"density profile along {where}: no significant band in {obj.num_frames} frames"
    speed = (f"speed {obj.band_speed:.3g} (length per time unit)" if math.isfinite(obj.band_speed)
             else "no speed (see notes)")
    return (f"density profile along {where}: bands in {obj.frames_with_bands} of {obj.num_frames} frames "
            f"({obj.band_count} in the last), width {obj.band_width:.3g}, {speed}")


def summary_lines(results) -> list[str]:
    from ..analysis.base import format_value

    lines = []
    for name, obj in results.items():
        if name == "polar":
            lines.append(f"polar order: <phi> {format_value(obj.mean, obj.mean_error, ' ± ')}, "
                         f"chi {format_value(obj.susceptibility, obj.susceptibility_error, ' ± ')}, "
                         f"G {format_value(obj.binder, obj.binder_error, ' ± ')} "
                         f"(autocorrelation time {obj.tau_time:.3g} time units, {obj.samples} values)")
        elif name == "species":
            lines.append("polar order per species: " + ", ".join(
                f"{s} {format_value(obj[s].mean, obj[s].mean_error, ' ± ')}" for s in obj.names))
        elif name == "nematic":
            lines.append(f"nematic order: <S> {format_value(obj.mean, obj.mean_error, ' ± ')} "
                         f"(autocorrelation time {obj.tau_time:.3g} time units, {obj.samples} values)")
        elif name == "fluctuations":
            alpha = format_value(obj.alpha, obj.alpha_error, ' ± ') if math.isfinite(obj.alpha) else "n/a (see notes)"
            lines.append(f"number fluctuations: alpha {alpha}")
        elif name == "structure":
            lines.append(f"structure factor: S(k) {format_value(obj.s[0], obj.s_error[0], ' ± ')} at k = "
                         f"{obj.k[0]:.3g}, {format_value(obj.s[-1], obj.s_error[-1], ' ± ')} at k = {obj.k[-1]:.3g} "
                         f"({len(obj.k)} shells, from {obj.source})")
        elif name == "correlation":
            lines.append(f"velocity correlation: first zero of C(r) at r = {obj.correlation_length:.4g}"
                         if math.isfinite(obj.correlation_length) else
                         f"velocity correlation: no zero of C(r) up to r_max = {obj.r_max_used:.4g} (see notes)")
        elif name == "profile":
            lines.append(profile_line(obj))
        elif name == "clusters":
            links = f"each with its {obj.k_used} nearest" if obj.k_used else f"closer than {obj.radius_used:g}"
            lines.append(f"clusters ({links}): largest {obj.largest_fraction_mean:.3f} of N (mean over {obj.num_frames} "
                         f"frames; last frame {obj.largest_fraction:.3f}), weight-average size "
                         f"{format_value(obj.weight_average_size)}, number-average size "
                         f"{format_value(obj.number_average_size)}")
        elif name == "boxcount":
            error = "no error estimate from two box sizes" if math.isnan(obj.dimension_error) else None
            lines.append(f"box counting: D {format_value(obj.dimension, obj.dimension_error, ' ± ')}"
                         + (f" ({error})" if error else ""))
        elif name == "msd":
            lines.append(f"MSD: {len(obj.lag_steps)} lags, {obj.msd[-1]:.4g} at lag time {obj.lag_times[-1]:.4g}")
    return lines
