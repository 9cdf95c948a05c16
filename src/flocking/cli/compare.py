"""``flocking compare RUN_A RUN_B``: whether two runs hold the same data, exactly.

Two runs of the same configuration (a ``--config`` rerun, a run stopped and resumed, a run
extended to the length of another) hold identical data: every frame's arrays, every row of
the observables, the final state. Their ``trajectory.gsd`` files are not the same bytes:
where gsd places a frame's chunks and its index in the file follows when frames were
flushed (at least once a second while a run goes on), and a resume rewrites the file.
This command compares what a reader sees, value by value, with no tolerance.

>>> import flocking, os, tempfile
>>> folder = tempfile.mkdtemp()
>>> for name in ("a", "b"):
...     sim = flocking.Simulation(flocking.Model(n=50, box=5.0, seed=3))
...     sim.writers.append(flocking.GSDWriter(os.path.join(folder, name, "trajectory.gsd"), every=5))
...     os.makedirs(os.path.join(folder, name))
...     sim.run(10)
>>> differences(os.path.join(folder, "a"), os.path.join(folder, "b"))
[]
"""

from __future__ import annotations

import csv
import json
import os

import click
import numpy as np

from ..model import ParameterError

#: what a GSD frame of a run holds, as gsd.hoomd reads it: (group, attribute)
FRAME_DATA = (("configuration", "step"), ("configuration", "dimensions"), ("configuration", "box"),
              ("particles", "N"), ("particles", "position"), ("particles", "velocity"))


def trajectory_of(path: str) -> str:
    """The trajectory of a run folder, or ``path`` itself if it is a file."""
    if os.path.isdir(path):
        path = os.path.join(path, "trajectory.gsd")
    if not os.path.isfile(path):
        raise ParameterError(f"run: {path!r} is not a run folder or a trajectory")
    return path


def _array_difference(name: str, a, b) -> str | None:
    a, b = np.atleast_1d(a), np.atleast_1d(b)
    if a.shape != b.shape:
        return f"{name}: shapes {a.shape} and {b.shape}"
    if a.dtype != b.dtype:
        return f"{name}: types {a.dtype} and {b.dtype}"
    same = (a == b) | ((a != a) & (b != b))  # two NaNs count as equal
    if same.all():
        return None
    rows = same.reshape(len(same), -1).all(axis=1) if same.ndim > 1 else same
    diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
    return (f"{name}: {int((~rows).sum())} of {len(rows)} differ "
            f"(largest difference {float(np.nanmax(np.where(same, 0.0, diff))):.3g})")


def compare_trajectories(path_a: str, path_b: str) -> list[str]:
    """Differences between the frames (and the model parameters) of two GSD files."""
    import gsd.hoomd

    from ..trajectory import Trajectory

    found = []
    params = []
    for path in (path_a, path_b):
        with Trajectory(path) as t:
            params.append((t.parameters or {}).get("model"))
    if params[0] != params[1]:
        a, b = params[0] or {}, params[1] or {}
        keys = [k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        found.append("parameters: " + ", ".join(f"{k} {a.get(k)!r} and {b.get(k)!r}" for k in keys))
    with gsd.hoomd.open(path_a, mode="r") as ta, gsd.hoomd.open(path_b, mode="r") as tb:
        if len(ta) != len(tb):
            found.append(f"trajectory: {len(ta)} and {len(tb)} frames")
        differing = []
        for i in range(min(len(ta), len(tb))):
            fa, fb = ta[i], tb[i]
            frame = [d for group, attr in FRAME_DATA
                     if (d := _array_difference(f"{group}.{attr}", getattr(getattr(fa, group), attr),
                                                getattr(getattr(fb, group), attr)))]
            if frame:
                differing.append((i, int(fa.configuration.step), frame))
        if differing:
            i, step, what = differing[0]
            found.append(f"trajectory: {len(differing)} frames differ; the first is frame {i} (step {step}): "
                         + "; ".join(what))
    return found


def read_observables(path: str) -> tuple[list[str], list[list[str]]]:
    """Header and rows of an ``observables.csv``, as text (the writer stores each double's
    ``repr``, which gives the same double back, so equal text is equal values)."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    return (rows[0], rows[1:]) if rows else ([], [])


def compare_observables(path_a: str, path_b: str) -> list[str]:
    """Differences between two observables tables, row by row and exactly."""
    (ha, ra), (hb, rb) = read_observables(path_a), read_observables(path_b)
    found = []
    if ha != hb:
        found.append(f"observables: columns {ha} and {hb}")
        return found
    if len(ra) != len(rb):
        found.append(f"observables: {len(ra)} and {len(rb)} rows")
    differing = [i for i, (x, y) in enumerate(zip(ra, rb)) if x != y]  # repr of a double: the same text, the same bits
    if differing:
        i = differing[0]
        found.append(f"observables: {len(differing)} rows differ; the first is step {ra[i][0]}: "
                     f"{','.join(ra[i])} and {','.join(rb[i])}")
    return found


def compare_checkpoints(path_a: str, path_b: str) -> list[str]:
    """Differences between the states (and backend memories) saved in two checkpoints."""
    found = []
    with np.load(path_a) as ca, np.load(path_b) as cb:
        names = sorted((set(ca.files) | set(cb.files)) - {"meta"})
        for name in names:
            if name not in ca.files or name not in cb.files:
                found.append(f"checkpoint: {name} only in {'the first' if name in ca.files else 'the second'}")
            elif d := _array_difference(f"checkpoint: {name}", ca[name], cb[name]):
                found.append(d)
        ma, mb = (json.loads(c["meta"].tobytes().decode()) for c in (ca, cb))
    for key in ("step", "origin"):
        if ma.get(key) != mb.get(key):
            found.append(f"checkpoint: {key} {ma.get(key)} and {mb.get(key)}")
    return found


def differences(run_a: str, run_b: str) -> list[str]:
    """Every difference between the data of two runs (folders or GSD files), in words; empty
    if they are identical. Folders also compare ``observables.csv`` and ``checkpoint.npz``
    (a file that only one of them has is a difference)."""
    try:
        found = compare_trajectories(trajectory_of(run_a), trajectory_of(run_b))
    except (OSError, RuntimeError, ValueError, KeyError) as err:  # gsd's ways of refusing a file
        raise ParameterError(f"run: cannot read a trajectory of {run_a!r} or {run_b!r} ({err})") from None
    if os.path.isdir(run_a) and os.path.isdir(run_b):
        for name, compare in (("observables.csv", compare_observables), ("checkpoint.npz", compare_checkpoints)):
            pa, pb = os.path.join(run_a, name), os.path.join(run_b, name)
            if os.path.isfile(pa) and os.path.isfile(pb):
                try:
                    found += compare(pa, pb)
                except (OSError, ValueError, KeyError, EOFError) as err:
                    raise ParameterError(f"run: cannot read {pa!r} or {pb!r} ({err})") from None
            elif os.path.isfile(pa) or os.path.isfile(pb):
                found.append(f"{name}: only in {run_a if os.path.isfile(pa) else run_b}")
    return found


@click.command(short_help="Whether two runs hold the same data, exactly.")
@click.argument("run_a", type=click.Path())
@click.argument("run_b", type=click.Path())
def compare(run_a, run_b):
    """Say whether two runs hold the same data, exactly: exit code 0 if so, 1 if not.

    RUN_A and RUN_B are run folders (trajectory.gsd, observables.csv, checkpoint.npz) or
    GSD files. Every frame's step, box, positions and velocities, every row of the
    observables and the final state are compared value by value. The trajectory files
    themselves may differ in bytes: gsd lays a file out as frames were flushed.

    \b
    Examples:
      flocking run --config runs/run-0001/config.toml --out again
      flocking compare runs/run-0001 again
    """
    found = differences(run_a, run_b)
    if found:
        for line in found:
            click.echo(f"flocking compare: {line}")
        click.get_current_context().exit(1)
    click.echo(f"flocking compare: identical data in {run_a} and {run_b}")
