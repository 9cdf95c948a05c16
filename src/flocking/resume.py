"""Bringing a run folder back to its last checkpoint, so that the run can go on exactly.

After a stop or a crash the trajectory and the observables may hold steps beyond the last
checkpoint, and a frame written at a stop between two triggers. :func:`rewind` keeps what an
uninterrupted run would have written up to the checkpoint and nothing else, so that
continuing from the checkpoint gives the same files as never stopping. Each file is rebuilt
next to itself and renamed over it: a crash during :func:`rewind` leaves the old file.
"""

from __future__ import annotations

import os

import gsd.hoomd

from .files import write_text


def rewind(folder: str, step: int, origin: int, every: int) -> None:
    """Trim ``trajectory.gsd``, ``observables.csv`` and ``fields.nc`` of ``folder`` to ``step``."""
    trajectory = os.path.join(folder, "trajectory.gsd")
    if os.path.exists(trajectory):
        rewind_trajectory(trajectory, step, origin, every)
    observables = os.path.join(folder, "observables.csv")
    if os.path.exists(observables):
        rewind_observables(observables, step)
    fields = os.path.join(folder, "fields.nc")
    if os.path.exists(fields):
        from .fields import rewind as rewind_fields

        rewind_fields(fields, step)


def _on_grid(s: int, origin: int, every: int) -> bool:
    return s == origin or (every > 0 and (s - origin) % every == 0)


def rewind_trajectory(path: str, step: int, origin: int, every: int) -> None:
    """Keep the frames at or before ``step`` that fall on the writer's trigger grid."""
    with gsd.hoomd.open(path, mode="r") as src:
        steps = [int(src[i].configuration.step) for i in range(len(src))]
        keep = [i for i, s in enumerate(steps) if s <= step and _on_grid(s, origin, every)]
        if keep == list(range(len(steps))):
            return
        tmp = path + ".tmp"
        with gsd.hoomd.open(tmp, mode="w") as dst:
            for i in keep:
                dst.append(src[i])
    os.replace(tmp, path)


def rewind_observables(path: str, step: int) -> None:
    """Keep the header and the complete rows up to ``step`` (a torn last line goes too)."""
    with open(path, encoding="utf-8") as f:
        lines = f.read().split("\n")
    kept = [lines[0]]
    for line in lines[1:]:
        fields = line.split(",")
        if len(fields) != 2 or not fields[0].isdigit() or not fields[1]:
            break  # a torn line can only be the last one
        if int(fields[0]) > step:
            break
        kept.append(line)
    write_text(path, "\n".join(kept) + "\n")
