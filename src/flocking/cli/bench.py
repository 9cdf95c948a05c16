"""``flocking bench``: throughput of the CPU backend next to reference implementations."""

from __future__ import annotations

import click

from ..model import ParameterError
from . import options as opt


@click.command(short_help="Particle-steps per second, beside reference codes.")
@click.option("--full", is_flag=True, help="The whole table (N up to 1e7; tens of minutes). Default: quick, small N.")
@click.option("--refs", type=click.Path(file_okay=False), default=None,
              help="Folder holding kdtree_reference.py. [default: benchmarks/ next to the package source]")
@opt.out("Folder for results.json, results.md and throughput.png.", "bench-results")
@click.option("--repeats", type=int, default=3, show_default=True, help="Timed runs per case (the median is kept).")
@click.option("--group", "groups", multiple=True,
              help="Only these groups (2d-metric, 3d-metric, topological, vectorial, delay, threads); repeatable.")
@click.option("--no-memory", is_flag=True, help="Skip the peak-memory probes.")
def bench(full, refs, out, repeats, groups, no_memory):
    """Particle-steps per second of standard cases, side by side with references.

    Every case runs on flocking's CPU backend and, in the same process, on SciPy's
    cKDTree + sparse-matrix approach and on pyvicsek's C++ kernel (when installed, same
    thread count); the speed-up column is flocking's throughput over theirs.
    """
    from .. import throughput as suite

    out = out or "bench-results"
    opt.check_folder("out", out)
    if repeats < 1:
        raise ParameterError(f"repeats: must be at least 1 (got {repeats})")
    known = {c.group for c in suite.standard_cases(full)}
    for g in groups:
        if g not in known:
            raise ParameterError(f"group: must be one of {', '.join(sorted(known))} (got {g!r})")
    ref_dir = suite.find_refs(refs)
    if ref_dir is None:
        click.echo("note: benchmarks/ not found next to the package: kd-tree reference skipped (use --refs DIR)", err=True)
    result = suite.run_suite(full=full, refs=ref_dir, repeats=repeats, memory=not no_memory, groups=tuple(groups),
                             log=click.echo)
    for path in suite.write_results(result, out):
        click.echo(f"wrote {path}")
